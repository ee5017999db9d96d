//! Grayscale PNG frames: Mono8 as 8-bit PNG; Mono16 as 16-bit PNG with the significant bits
//! left-aligned and an sBIT chunk (the PNG convention), so a 12-bit frame reads back as 12-bit.
use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::Path;

use csmetro_hal::{Frame, Pixels};

#[derive(Debug, thiserror::Error)]
pub enum IoError {
    #[error("{path}: {source}")]
    File {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: not a readable PNG: {message}")]
    Png { path: String, message: String },
    #[error("{path}: unsupported PNG ({0}); expected 8- or 16-bit grayscale", path = .1)]
    Unsupported(String, String),
    #[error("frame has {got} pixels, expected {expected}")]
    Size { got: usize, expected: usize },
}

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
    let png_err = |e: png::DecodingError| IoError::Png {
        path: ps.clone(),
        message: e.to_string(),
    };
    let decoder = png::Decoder::new(BufReader::new(file));
    let mut reader = decoder.read_info().map_err(png_err)?;
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
