//! A subcommand's flags given as a list (a sweep cell's `bench` flags, an experiment's
//! `track` and `replay` flights), parsed exactly as the command line parses them: the same
//! defaults, the same validation, one copy of each flag's definition.

use anyhow::Result;

use crate::cli_error::bad_input;

/// `FLAGS` parsed as `amstack COMMAND FLAGS` parses them (`T` is that command's flags); a bad
/// flag is bad input, the first line of clap's message.
pub(crate) fn parse<T: clap::Args>(command: &str, flags: &[String]) -> Result<T> {
    let first_line = |e: clap::Error| {
        let text = e.render().to_string();
        bad_input(
            text.lines()
                .find(|l| !l.trim().is_empty())
                .unwrap_or("bad flags")
                .trim_start_matches("error: ")
                .to_owned(),
        )
    };
    let matches = T::augment_args(clap::Command::new("amstack"))
        .try_get_matches_from(std::iter::once(command.to_owned()).chain(flags.iter().cloned()))
        .map_err(first_line)?;
    T::from_arg_matches(&matches).map_err(first_line)
}
