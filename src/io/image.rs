//! Images: PNG (png crate) and animated GIF (gif crate, NeuQuant palette per frame).

use crate::render::Image;
use std::io::Write;

/// Writes `im` as an 8-bit RGB PNG.
pub fn write_png(w: &mut dyn Write, im: &Image) -> std::io::Result<()> {
    let mut enc = png::Encoder::new(w, im.width, im.height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc.write_header().map_err(std::io::Error::other)?;
    writer
        .write_image_data(&im.rgb)
        .map_err(std::io::Error::other)?;
    writer.finish().map_err(std::io::Error::other)
}

/// Reads an 8-bit RGB or RGBA PNG (alpha dropped), e.g. a golden reference image.
pub fn read_png(path: &std::path::Path) -> Result<Image, String> {
    let file = std::fs::File::open(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut dec = png::Decoder::new(std::io::BufReader::new(file));
    dec.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = dec
        .read_info()
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| format!("{}: image too large", path.display()))?;
    let mut buf = vec![0; size];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let channels = match info.color_type {
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        other => {
            return Err(format!(
                "{}: unsupported PNG colour type {other:?}",
                path.display()
            ))
        }
    };
    let mut im = Image::new(info.width, info.height);
    for (dst, src) in im
        .rgb
        .chunks_exact_mut(3)
        .zip(buf[..info.buffer_size()].chunks_exact(channels))
    {
        dst.copy_from_slice(&src[..3]);
    }
    Ok(im)
}

/// Writes `frames` (all the same size, at most 65535 x 65535) as a looping animated GIF
/// with `delay_cs` hundredths of a second per frame. Each frame gets its own 256-colour
/// palette (NeuQuant, as the gif crate implements it); frames are quantized in parallel.
pub fn write_gif(w: &mut dyn Write, frames: &[Image], delay_cs: u16) -> std::io::Result<()> {
    use rayon::prelude::*;
    let Some(first) = frames.first() else {
        return Err(std::io::Error::other(
            "an animation needs at least one frame",
        ));
    };
    let (width, height) = (
        u16::try_from(first.width).map_err(std::io::Error::other)?,
        u16::try_from(first.height).map_err(std::io::Error::other)?,
    );
    let encoded: Vec<gif::Frame<'static>> = frames
        .par_iter()
        .map(|f| {
            let mut fr = gif::Frame::from_rgb_speed(width, height, &f.rgb, 10);
            fr.delay = delay_cs;
            fr
        })
        .collect();
    let mut enc = gif::Encoder::new(w, width, height, &[]).map_err(std::io::Error::other)?;
    enc.set_repeat(gif::Repeat::Infinite)
        .map_err(std::io::Error::other)?;
    for f in &encoded {
        enc.write_frame(f).map_err(std::io::Error::other)?;
    }
    Ok(())
}
