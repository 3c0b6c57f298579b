//! Files: meshes (OBJ, PLY), images (PNG, GIF), the one bounded reader every input goes
//! through ([`read_text`]) and the atomic write every output goes through.
//!
//! Files are written to a temporary file of their own and renamed into place, so a reader
//! (or a run that fails later) never sees half a file: what was written before an error
//! stays valid. The temporary is created exclusively (`create_new`: an existing file or
//! a symbolic link planted at its name is an error, never followed) under a name no
//! other writer uses (`.NAME.<process>.<counter>.tmp`), and the rename replaces whatever
//! entry `NAME` was, a symbolic link included, without writing through it.

mod mesh;

pub use mesh::{
    edge_uses, is_surface_file, obj_vertex_line, parse_obj, parse_obj_uv, parse_off, read_obj,
    read_obj_uv, read_off, read_surface, write_obj, write_ply, Mesh, MeshRef, ReadError,
};
mod image;
pub use image::{read_png, write_gif, write_png, Image};

use std::io::{BufWriter, Read, Write};
use std::path::Path;

/// `v` rounded for people (summaries, plot labels): up to 4 significant digits without
/// trailing zeros (`0.03333`, `1.179`, `480`), in exponent form outside 1e-3 to 1e5
/// (`2.50e-7`). Files keep full precision; this is for what a person reads.
pub fn human(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 || !a.is_finite() {
        return format!("{}", if a == 0.0 { 0.0 } else { v });
    }
    if !(1e-3..1e5).contains(&a) {
        return format!("{v:.2e}");
    }
    let decimals = (3 - a.log10().floor() as i32).clamp(0, 6) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// The most characters of one message an error shows: what input it echoes (a token, a
/// line) is cut there, so that a 5 MB line does not come back as a 5 MB message.
pub const MAX_MESSAGE: usize = 400;

/// `s` cut to at most `max` characters (at a character boundary), saying how many were
/// left out.
pub fn clip(s: &str, max: usize) -> std::borrow::Cow<'_, str> {
    match s.char_indices().nth(max) {
        None => std::borrow::Cow::Borrowed(s),
        Some((cut, _)) => std::borrow::Cow::Owned(format!(
            "{}... ({} more characters)",
            &s[..cut],
            s[cut..].chars().count()
        )),
    }
}

/// Reads a text input file through the one bounded reader: regular files only (devices,
/// FIFOs and sockets are refused before they are opened: they may never end), at most
/// `max_bytes` bytes (checked on the file's size before reading and again while reading;
/// see [`crate::limits::Limits::max_file_bytes`]), and UTF-8 (an invalid byte is reported
/// with its line and byte offset).
pub fn read_text(path: &Path, max_bytes: u64) -> Result<String, ReadError> {
    let name = path.display().to_string();
    let err = |line: usize, message: String| ReadError {
        path: name.clone(),
        line,
        message,
    };
    let meta = std::fs::metadata(path).map_err(|e| err(0, e.to_string()))?;
    if !meta.is_file() {
        let what = if meta.is_dir() {
            "a folder"
        } else {
            "not a regular file (a device, FIFO or socket)"
        };
        return Err(err(0, format!("{what}: only regular files are read")));
    }
    let too_big = |len: u64| {
        err(
            0,
            format!(
                "{} is larger than the input limit of {}",
                crate::limits::Bytes(len as f64),
                crate::limits::Bytes(max_bytes as f64)
            ),
        )
    };
    if meta.len() > max_bytes {
        return Err(too_big(meta.len()));
    }
    let file = std::fs::File::open(path).map_err(|e| err(0, e.to_string()))?;
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(max_bytes.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|e| err(0, e.to_string()))?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_big(bytes.len() as u64));
    }
    String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let before = &e.as_bytes()[..at];
        let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
        let column = at - before.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
        err(
            line,
            format!(
                "not UTF-8 text: invalid byte 0x{:02x} at byte {at} of the file (byte {} of the line)",
                e.as_bytes()[at],
                column + 1
            ),
        )
    })
}

/// A new, exclusively created temporary file beside `path` (see the module docs), and its
/// name.
fn create_temporary(path: &Path) -> std::io::Result<(std::fs::File, std::path::PathBuf)> {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path
        .file_name()
        .ok_or_else(|| std::io::Error::other("not a file name"))?
        .to_string_lossy();
    let dir = path.parent().unwrap_or(Path::new(""));
    for _ in 0..100 {
        let k = COUNTER.fetch_add(1, Ordering::Relaxed);
        let tmp = dir.join(format!(".{name}.{}.{k}{TEMP_SUFFIX}", std::process::id()));
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
        {
            Ok(f) => return Ok((f, tmp)),
            // Taken (by a stale file or a planted link): another name.
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
    Err(std::io::Error::new(
        std::io::ErrorKind::AlreadyExists,
        format!("no free temporary name beside {}", path.display()),
    ))
}

/// What the names of temporary files end in (see [`remove_stale`]).
pub const TEMP_SUFFIX: &str = ".tmp";

/// Writes a file atomically through `write` (an exclusive temporary file, then a rename;
/// see the module docs). On an error the temporary is removed and `path` is untouched.
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let (file, tmp) = create_temporary(path)?;
    let result = (|| {
        let mut w = BufWriter::new(file);
        write(&mut w)?;
        w.flush()
    })()
    .and_then(|_| std::fs::rename(&tmp, path));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Creates `path` for writing as a stream (a log appended to as a run goes): an exclusive
/// temporary file renamed into place at once, so that a symbolic link planted at `path`
/// is replaced, not written through.
pub fn create_replacing(path: &Path) -> std::io::Result<std::fs::File> {
    let (file, tmp) = create_temporary(path)?;
    if let Err(e) = std::fs::rename(&tmp, path) {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    Ok(file)
}

/// Removes, in `dir`, the files an earlier run left that a new run would mix with its own:
/// those whose names `is_ours` accepts, and temporaries of interrupted writes (hidden
/// names ending in [`TEMP_SUFFIX`]). Only files are removed (a symbolic link itself, never
/// what it points to); a missing folder is nothing to clean. Returns how many went.
pub fn remove_stale(dir: &Path, is_ours: impl Fn(&str) -> bool) -> std::io::Result<usize> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(e),
    };
    let mut removed = 0;
    for entry in entries {
        let entry = entry?;
        let name = entry.file_name().to_string_lossy().into_owned();
        let temporary = name.starts_with('.') && name.ends_with(TEMP_SUFFIX);
        // `file_type` does not follow links: a link is removed as a link.
        if (temporary || is_ours(&name)) && !entry.file_type()?.is_dir() {
            std::fs::remove_file(entry.path())?;
            removed += 1;
        }
    }
    Ok(removed)
}

/// Writes `samples` as a 16-bit mono WAV at `sample_rate` (hound), scaled so the loudest
/// sample is 0.9 of full scale (silence stays zero); through a temporary file, so an
/// existing file stays whole if writing fails.
pub fn write_wav(path: &Path, samples: &[f64], sample_rate: u32) -> std::io::Result<()> {
    let peak = samples.iter().fold(0.0f64, |a, &b| a.max(b.abs()));
    let scale = if peak > 0.0 && peak.is_finite() {
        0.9 * i16::MAX as f64 / peak
    } else {
        0.0
    };
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut bytes = std::io::Cursor::new(Vec::with_capacity(44 + 2 * samples.len()));
    {
        let mut w = hound::WavWriter::new(&mut bytes, spec).map_err(std::io::Error::other)?;
        for &s in samples {
            w.write_sample((s * scale).round() as i16)
                .map_err(std::io::Error::other)?;
        }
        w.finalize().map_err(std::io::Error::other)?;
    }
    write_atomically(path, |w| w.write_all(bytes.get_ref()))
}
