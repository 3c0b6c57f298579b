//! 8-bit RGB images (box-filter downsampling, contact sheets) and their files: PNG (png
//! crate) and animated GIF (gif crate, NeuQuant palette per frame).

use std::io::Write;

/// An 8-bit sRGB-ish RGB image, row-major, top row first.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Image {
    /// Width (pixels).
    pub width: u32,
    /// Height (pixels).
    pub height: u32,
    /// `3 * width * height` bytes.
    pub rgb: Vec<u8>,
}

impl Image {
    /// A black image.
    pub fn new(width: u32, height: u32) -> Image {
        Image {
            width,
            height,
            rgb: vec![0; 3 * width as usize * height as usize],
        }
    }

    /// A uniform image.
    pub fn filled(width: u32, height: u32, rgb: [u8; 3]) -> Image {
        let mut im = Image::new(width, height);
        for p in im.rgb.chunks_exact_mut(3) {
            p.copy_from_slice(&rgb);
        }
        im
    }

    /// Pixel `(x, y)`.
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 3] {
        let i = 3 * (y as usize * self.width as usize + x as usize);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// The image shrunk by the integer factor `k` (box filter over k x k blocks; a
    /// remainder of fewer than k rows or columns is dropped).
    pub fn downsample(&self, k: u32) -> Image {
        let k = k.max(1);
        if k == 1 {
            return self.clone();
        }
        let (w, h) = ((self.width / k).max(1), (self.height / k).max(1));
        let mut out = Image::new(w, h);
        let kk = (k * k).min(self.width * self.height).max(1);
        for y in 0..h {
            for x in 0..w {
                let mut acc = [0u32; 3];
                for dy in 0..k.min(self.height) {
                    for dx in 0..k.min(self.width) {
                        let p = self.pixel(x * k + dx, y * k + dy);
                        for (a, c) in acc.iter_mut().zip(p) {
                            *a += c as u32;
                        }
                    }
                }
                let i = 3 * (y * w + x) as usize;
                for (o, a) in out.rgb[i..i + 3].iter_mut().zip(acc) {
                    *o = ((a + kk / 2) / kk) as u8;
                }
            }
        }
        out
    }

    /// Copies `src` into this image with its top-left corner at `(x0, y0)` (clipped).
    pub fn blit(&mut self, src: &Image, x0: u32, y0: u32) {
        for y in 0..src.height.min(self.height.saturating_sub(y0)) {
            let w = src.width.min(self.width.saturating_sub(x0)) as usize;
            let s = 3 * (y * src.width) as usize;
            let d = 3 * ((y0 + y) * self.width + x0) as usize;
            self.rgb[d..d + 3 * w].copy_from_slice(&src.rgb[s..s + 3 * w]);
        }
    }

    /// A contact sheet: `frames` (all the same size) in a grid of `cols` columns, each
    /// shrunk by `cols` so the sheet is about as wide as one frame, with a `gutter`-pixel
    /// white border between them. An empty list gives a 1 x 1 white image.
    pub fn contact_sheet(frames: &[Image], cols: u32, gutter: u32) -> Image {
        if frames.is_empty() {
            return Image::filled(1, 1, [255; 3]);
        }
        let cols = cols.clamp(1, frames.len() as u32);
        let rows = (frames.len() as u32).div_ceil(cols);
        let thumbs: Vec<Image> = frames.iter().map(|f| f.downsample(cols)).collect();
        let (tw, th) = (thumbs[0].width, thumbs[0].height);
        let mut sheet = Image::filled(
            cols * tw + (cols + 1) * gutter,
            rows * th + (rows + 1) * gutter,
            [255; 3],
        );
        for (i, t) in thumbs.iter().enumerate() {
            let (c, r) = (i as u32 % cols, i as u32 / cols);
            sheet.blit(t, gutter + c * (tw + gutter), gutter + r * (th + gutter));
        }
        sheet
    }
}

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
/// with `delay_cs` hundredths of a second per frame. After the first frame only the
/// rectangle that changed since the previous one is stored (the rest is kept on screen),
/// which is most of the saving for simulations over a still background. Each stored
/// rectangle gets its own 256-colour palette (NeuQuant, as the gif crate implements it);
/// rectangles are quantized in parallel.
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
    if frames
        .iter()
        .any(|f| (f.width, f.height) != (first.width, first.height))
    {
        return Err(std::io::Error::other("animation frames differ in size"));
    }
    let encoded: Vec<gif::Frame<'static>> = (0..frames.len())
        .into_par_iter()
        .map(|k| {
            let [x0, y0, x1, y1] = if k == 0 {
                [0, 0, first.width, first.height]
            } else {
                changed_rect(&frames[k - 1], &frames[k])
            };
            let (w, h) = (x1 - x0, y1 - y0);
            let mut rgb = Vec::with_capacity(3 * (w * h) as usize);
            for y in y0..y1 {
                let row = 3 * (y * first.width) as usize;
                rgb.extend_from_slice(&frames[k].rgb[row + 3 * x0 as usize..row + 3 * x1 as usize]);
            }
            let mut fr = gif::Frame::from_rgb_speed(w as u16, h as u16, &rgb, 10);
            fr.left = x0 as u16;
            fr.top = y0 as u16;
            fr.delay = delay_cs;
            fr.dispose = gif::DisposalMethod::Keep;
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

/// The smallest rectangle `[x0, y0, x1, y1)` holding every pixel that differs between two
/// images of one size; a 1 x 1 rectangle when nothing changed (a GIF frame is not empty).
fn changed_rect(a: &Image, b: &Image) -> [u32; 4] {
    let (mut x0, mut y0, mut x1, mut y1) = (a.width, a.height, 0, 0);
    for y in 0..a.height {
        let row = 3 * (y * a.width) as usize..3 * ((y + 1) * a.width) as usize;
        let (ra, rb) = (&a.rgb[row.clone()], &b.rgb[row]);
        if ra == rb {
            continue;
        }
        let first = ra
            .chunks(3)
            .zip(rb.chunks(3))
            .position(|(p, q)| p != q)
            .unwrap_or(0) as u32;
        let last = ra
            .chunks(3)
            .zip(rb.chunks(3))
            .rposition(|(p, q)| p != q)
            .unwrap_or(0) as u32;
        x0 = x0.min(first);
        x1 = x1.max(last + 1);
        y0 = y0.min(y);
        y1 = y + 1;
    }
    if x1 == 0 {
        [0, 0, 1, 1]
    } else {
        [x0, y0, x1, y1]
    }
}
