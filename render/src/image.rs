//! A rendered frame: 8-bit RGB, rows top to bottom, and its PNG encoding.

use std::io::Write;

use crate::error::RenderError;

/// An RGB8 image, `height` rows of `width` pixels, top row first; `rgb.len() = 3·w·h`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Image {
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// Pixels, R G B per pixel, row-major.
    pub rgb: Vec<u8>,
}

impl Image {
    /// The pixel at column `x`, row `y` (None outside).
    pub fn pixel(&self, x: u32, y: u32) -> Option<[u8; 3]> {
        if x >= self.width || y >= self.height {
            return None;
        }
        let i = 3 * (y as usize * self.width as usize + x as usize);
        self.rgb.get(i..i + 3).map(|p| [p[0], p[1], p[2]])
    }

    /// Writes the image as a PNG (8-bit RGB, default compression).
    pub fn write_png<W: Write>(&self, writer: W) -> Result<(), RenderError> {
        let mut encoder = png::Encoder::new(writer, self.width, self.height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut w = encoder
            .write_header()
            .map_err(|e| RenderError::Png(e.to_string()))?;
        w.write_image_data(&self.rgb)
            .map_err(|e| RenderError::Png(e.to_string()))?;
        w.finish().map_err(|e| RenderError::Png(e.to_string()))
    }

    /// The PNG encoding in memory.
    pub fn to_png(&self) -> Result<Vec<u8>, RenderError> {
        let mut bytes = Vec::new();
        self.write_png(&mut bytes)?;
        Ok(bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trips() {
        let img = Image {
            width: 2,
            height: 1,
            rgb: vec![255, 0, 0, 0, 0, 255],
        };
        let bytes = img.to_png().unwrap_or_default();
        let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut reader = match decoder.read_info() {
            Ok(r) => r,
            Err(e) => panic!("{e}"),
        };
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = match reader.next_frame(&mut buf) {
            Ok(i) => i,
            Err(e) => panic!("{e}"),
        };
        assert_eq!((info.width, info.height), (2, 1));
        assert_eq!(&buf[..6], &img.rgb[..]);
        assert_eq!(img.pixel(1, 0), Some([0, 0, 255]));
        assert_eq!(img.pixel(2, 0), None);
    }
}
