//! 8-bit RGB images and their PNG encoding, used by every layer that writes or reads a picture (render,
//! report's plots, serve's page). lobe marks its own PNGs with a tEXt chunk ([`PNG_SOFTWARE`]) so that
//! [`crate::base::output`] can tell a file lobe wrote from one it must not overwrite ([`is_lobe_png`]).
//!
//! PNG encoding is one serial pass (the "up" filter, then fdeflate's fastest mode); measured against the
//! render in BENCHMARKS.md.

/// An 8-bit RGB image, row-major, top row first.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<u8>,
}

/// The tEXt key/value lobe writes into every PNG, so it can recognise its own files before overwriting.
pub(crate) const PNG_SOFTWARE: (&str, &str) = ("Software", "lobe");

impl Image {
    pub fn new(width: usize, height: usize) -> Image {
        Image { width, height, rgb: vec![0; width * height * 3] }
    }

    pub fn pixel(&self, x: usize, y: usize) -> [u8; 3] {
        let o = (y * self.width + x) * 3;
        [self.rgb[o], self.rgb[o + 1], self.rgb[o + 2]]
    }

    pub(crate) fn set(&mut self, x: usize, y: usize, c: [u8; 3]) {
        let o = (y * self.width + x) * 3;
        self.rgb[o..o + 3].copy_from_slice(&c);
    }

    /// PNG bytes (8-bit RGB) with lobe's tEXt marker.
    pub fn encode_png(&self) -> Result<Vec<u8>, String> {
        let mut buf = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut buf, self.width as u32, self.height as u32);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            // The "up" filter and fdeflate's fastest mode: `Fast` chose a filter per row by trying all five
            // (most of the encode time at 4096²); on rendered images "up" compresses about as well.
            enc.set_compression(png::Compression::Fastest);
            enc.add_text_chunk(PNG_SOFTWARE.0.into(), PNG_SOFTWARE.1.into()).map_err(|e| e.to_string())?;
            let mut w = enc.write_header().map_err(|e| format!("PNG encoder: {e}"))?;
            w.write_image_data(&self.rgb).map_err(|e| format!("PNG encoder: {e}"))?;
            w.finish().map_err(|e| format!("PNG encoder: {e}"))?;
        }
        Ok(buf)
    }

    /// Decodes an 8-bit RGB or RGBA PNG (alpha is dropped).
    pub fn decode_png(bytes: &[u8]) -> Result<Image, String> {
        let dec = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut reader = dec.read_info().map_err(|e| format!("not a readable PNG: {e}"))?;
        let size = reader.output_buffer_size().ok_or("PNG too large")?;
        let mut data = vec![0; size];
        let info = reader.next_frame(&mut data).map_err(|e| format!("not a readable PNG: {e}"))?;
        if info.bit_depth != png::BitDepth::Eight {
            return Err("only 8-bit PNGs are supported".into());
        }
        let (w, h) = (info.width as usize, info.height as usize);
        let rgb = match info.color_type {
            png::ColorType::Rgb => data[..w * h * 3].to_vec(),
            png::ColorType::Rgba => data[..w * h * 4].chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect(),
            other => return Err(format!("unsupported PNG colour type {other:?}")),
        };
        Ok(Image { width: w, height: h, rgb })
    }
}

/// Is `bytes` a PNG carrying lobe's tEXt marker?
pub fn is_lobe_png(bytes: &[u8]) -> bool {
    let dec = png::Decoder::new(std::io::Cursor::new(bytes));
    match dec.read_info() {
        Ok(r) => r
            .info()
            .uncompressed_latin1_text
            .iter()
            .any(|t| t.keyword == PNG_SOFTWARE.0 && t.text == PNG_SOFTWARE.1),
        Err(_) => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::output::{check as check_output_path, write_atomic};

    #[test]
    fn png_round_trip_and_marker() {
        let mut im = Image::new(3, 2);
        im.set(2, 1, [1, 2, 3]);
        let bytes = im.encode_png().unwrap();
        assert!(is_lobe_png(&bytes));
        assert_eq!(Image::decode_png(&bytes).unwrap(), im);
        assert!(!is_lobe_png(b"hello"));
    }

    #[test]
    fn refuses_to_clobber_foreign_files() {
        let dir = std::env::temp_dir().join(format!("lobe-img-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("notes.png");
        std::fs::write(&p, "precious").unwrap();
        assert!(check_output_path(&p, false, is_lobe_png).is_err());
        assert!(check_output_path(&p, true, is_lobe_png).is_ok());
        let ours = Image::new(1, 1).encode_png().unwrap();
        write_atomic(&p, &ours).unwrap();
        assert!(check_output_path(&p, false, is_lobe_png).is_ok());
        assert!(check_output_path(&dir.join("missing/x.png"), false, is_lobe_png).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
