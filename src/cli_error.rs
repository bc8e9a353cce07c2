//! Errors of the command line: bad input (exit 2) versus failure (exit 1).

use std::fmt;

/// The user's input was wrong: a flag value, a file that cannot be read or parsed. Exit 2.
#[derive(Debug)]
pub struct BadInput(pub String);

impl fmt::Display for BadInput {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for BadInput {}

/// Bad input, as an `anyhow::Error`.
pub fn bad_input(message: impl Into<String>) -> anyhow::Error {
    anyhow::Error::new(BadInput(message.into()))
}

/// The error and its causes on one line, each cause once: an error whose message already
/// quotes its source (`writing MCAP file …: {source}`) does not repeat it.
pub fn one_line(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let said = cause.to_string();
        if text.contains(said.as_str()) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&said);
    }
    text.split_whitespace().collect::<Vec<_>>().join(" ")
}
