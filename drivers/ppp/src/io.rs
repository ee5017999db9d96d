//! Grayscale PNG frames: Mono8 as 8-bit PNG; Mono16 as 16-bit PNG with the significant bits
//! left-aligned and an sBIT chunk (the PNG convention), so a 12-bit frame reads back as 12-bit.
use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::Path;

use csmetro_hal::{Frame, Pixels};

/// Why a PNG frame could not be written or read; messages name the file where there is one.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// Opening or creating the file failed.
    #[error("{path}: {source}")]
    File {
        /// The file.
        path: String,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// The PNG encoder or decoder failed (corrupt or truncated file).
    #[error("{path}: not a readable PNG: {message}")]
    Png {
        /// The file.
        path: String,
        /// The PNG library's message.
        message: String,
    },
    /// A readable PNG that is not 8- or 16-bit grayscale: (what it is, the file).
    #[error("{path}: unsupported PNG ({0}); expected 8- or 16-bit grayscale", path = .1)]
    Unsupported(String, String),
    /// The frame's pixel buffer does not hold `width * height` values.
    #[error("frame has {got} pixels, expected {expected}")]
    Size {
        /// Pixels in the buffer.
        got: usize,
        /// `width * height`.
        expected: usize,
    },
    /// The PNG header announces a frame above [`MAX_FRAME_SIDE`] or [`MAX_FRAME_PIXELS`].
    #[error("{path}: {width} x {height} px is larger than a frame may be ({MAX_FRAME_SIDE} px a side, {MAX_FRAME_PIXELS} px in all)")]
    TooLarge {
        /// The file.
        path: String,
        /// Announced width, px.
        width: u32,
        /// Announced height, px.
        height: u32,
    },
}

/// Largest frame side read, px (the paper's camera: 1024 x 768).
pub const MAX_FRAME_SIDE: u32 = 8192;
/// Largest frame read, px.
pub const MAX_FRAME_PIXELS: u64 = 1 << 24;
/// Most bytes the PNG decoder may allocate besides the frame (its own buffers).
const PNG_DECODER_BYTES: usize = 64 << 20;

/// Writes `frame` as a grayscale PNG.
pub fn write_png(path: &Path, frame: &Frame) -> Result<(), IoError> {
    let ps = path.display().to_string();
    let file = File::create(path).map_err(|source| IoError::File {
        path: ps.clone(),
        source,
    })?;
    let n = frame.width * frame.height;
    let png_err = |e: png::EncodingError| IoError::Png {
        path: ps.clone(),
        message: e.to_string(),
    };
    let mut info = png::Info::with_size(frame.width as u32, frame.height as u32);
    info.color_type = png::ColorType::Grayscale;
    // png 0.17 does not emit Info::sbit, so the chunk is written by hand after the header.
    let mut sbit = None;
    let data: Vec<u8> = match &frame.pixels {
        Pixels::Mono8(p) => {
            if p.len() != n {
                return Err(IoError::Size {
                    got: p.len(),
                    expected: n,
                });
            }
            info.bit_depth = png::BitDepth::Eight;
            p.clone()
        }
        Pixels::Mono16(p) => {
            if p.len() != n {
                return Err(IoError::Size {
                    got: p.len(),
                    expected: n,
                });
            }
            info.bit_depth = png::BitDepth::Sixteen;
            let bits = frame.bit_depth.clamp(9, 16);
            let shift = 16 - bits;
            sbit = Some(bits);
            p.iter().flat_map(|&v| (v << shift).to_be_bytes()).collect()
        }
    };
    let enc = png::Encoder::with_info(BufWriter::new(file), info).map_err(png_err)?;
    let mut writer = enc.write_header().map_err(png_err)?;
    if let Some(bits) = sbit {
        writer
            .write_chunk(png::chunk::sBIT, &[bits])
            .map_err(png_err)?;
    }
    writer.write_image_data(&data).map_err(png_err)?;
    writer.finish().map_err(png_err)
}

/// Reads an 8- or 16-bit grayscale PNG into a frame (timestamp 0).
pub fn read_png(path: &Path) -> Result<Frame, IoError> {
    let ps = path.display().to_string();
    let file = File::open(path).map_err(|source| IoError::File {
        path: ps.clone(),
        source,
    })?;
    decode_png(BufReader::new(file), ps)
}

/// Decodes an 8- or 16-bit grayscale PNG already read into memory (the caller bounded and
/// checked the file); `name` names it in errors.
pub fn png_from_bytes(bytes: &[u8], name: &str) -> Result<Frame, IoError> {
    decode_png(bytes, name.to_string())
}

fn decode_png(input: impl std::io::Read, ps: String) -> Result<Frame, IoError> {
    let png_err = |e: png::DecodingError| IoError::Png {
        path: ps.clone(),
        message: e.to_string(),
    };
    let decoder = png::Decoder::new_with_limits(
        input,
        png::Limits {
            bytes: PNG_DECODER_BYTES,
        },
    );
    let mut reader = decoder.read_info().map_err(png_err)?;
    // The header gives the size: refuse a huge frame before allocating its buffer.
    let (width, height) = (reader.info().width, reader.info().height);
    if width > MAX_FRAME_SIDE
        || height > MAX_FRAME_SIDE
        || u64::from(width) * u64::from(height) > MAX_FRAME_PIXELS
    {
        return Err(IoError::TooLarge {
            path: ps,
            width,
            height,
        });
    }
    let (ct, bd) = reader.output_color_type();
    let sbit = reader.info().sbit.as_ref().and_then(|s| s.first().copied());
    let mut buf = vec![0u8; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).map_err(png_err)?;
    let (w, h) = (info.width as usize, info.height as usize);
    if ct != png::ColorType::Grayscale {
        return Err(IoError::Unsupported(format!("color type {ct:?}"), ps));
    }
    let stride = info.line_size;
    match bd {
        png::BitDepth::Eight => {
            let mut px = Vec::with_capacity(w * h);
            for y in 0..h {
                px.extend_from_slice(&buf[y * stride..y * stride + w]);
            }
            Ok(Frame {
                width: w,
                height: h,
                bit_depth: 8,
                pixels: Pixels::Mono8(px),
                timestamp_s: 0.0,
            })
        }
        png::BitDepth::Sixteen => {
            let bits = sbit.filter(|b| (9..=16).contains(b)).unwrap_or(16);
            let shift = 16 - bits;
            let mut px = Vec::with_capacity(w * h);
            for y in 0..h {
                let row = &buf[y * stride..y * stride + 2 * w];
                px.extend(
                    row.chunks_exact(2)
                        .map(|c| u16::from_be_bytes([c[0], c[1]]) >> shift),
                );
            }
            Ok(Frame {
                width: w,
                height: h,
                bit_depth: bits,
                pixels: Pixels::Mono16(px),
                timestamp_s: 0.0,
            })
        }
        other => Err(IoError::Unsupported(format!("bit depth {other:?}"), ps)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A PNG header claiming `w` x `h` 8-bit gray and no pixel data.
    fn header_only(w: u32, h: u32) -> Vec<u8> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, w, h);
            enc.set_color(png::ColorType::Grayscale);
            enc.set_depth(png::BitDepth::Eight);
            let mut w = enc.write_header().unwrap();
            // One IDAT chunk starts the image data: enough for the header to be read.
            w.write_chunk(png::chunk::IDAT, &[0x78, 0x9c, 0x03, 0x00])
                .unwrap();
            drop(w);
        }
        out
    }

    #[test]
    fn a_huge_frame_is_refused_from_its_header_naming_the_file() {
        let dir = std::env::temp_dir().join(format!("csmetro-ppp-io-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("huge.png");
        std::fs::write(&p, header_only(20_000, 20_000)).unwrap();
        let e = read_png(&p).unwrap_err();
        assert!(matches!(e, IoError::TooLarge { width: 20_000, .. }), "{e}");
        assert!(e.to_string().contains("huge.png"), "{e}");
        let p2 = dir.join("wide.png");
        std::fs::write(&p2, header_only(MAX_FRAME_SIDE + 1, 1)).unwrap();
        assert!(matches!(read_png(&p2), Err(IoError::TooLarge { .. })));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_frame_round_trips() {
        let dir = std::env::temp_dir().join(format!("csmetro-ppp-rt-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("f.png");
        let f = Frame {
            width: 3,
            height: 2,
            bit_depth: 12,
            pixels: Pixels::Mono16(vec![0, 1, 4095, 7, 100, 2048]),
            timestamp_s: 0.0,
        };
        write_png(&p, &f).unwrap();
        let g = read_png(&p).unwrap();
        assert_eq!((g.width, g.height, g.bit_depth), (3, 2, 12));
        assert_eq!(g.pixels, f.pixels);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
