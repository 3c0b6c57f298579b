//! 8-bit RGB images: box-filter downsampling and contact sheets.

/// An 8-bit sRGB-ish RGB image, row-major, top row first.
#[derive(Clone, Debug, PartialEq, Eq)]
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
