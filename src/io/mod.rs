//! Files: meshes (OBJ, PLY), images (PNG, GIF), the one bounded reader every input goes
//! through ([`read_text`]) and the atomic write every output goes through.
//!
//! Files are written to `NAME.tmp` and renamed into place, so a reader (or a run that
//! fails later) never sees half a file: what was written before an error stays valid.

mod mesh;

pub use mesh::{
    parse_obj, parse_obj_uv, read_obj, read_obj_uv, write_obj, write_ply, Mesh, MeshRef, ReadError,
};
mod image;
pub use image::{read_png, write_gif, write_png, Image};

use std::io::{BufWriter, Read, Write};
use std::path::Path;

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

/// Writes a file atomically through `write` (temporary file, then rename).
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = std::path::PathBuf::from(tmp);
    {
        let mut w = BufWriter::new(std::fs::File::create(&tmp)?);
        write(&mut w)?;
        w.flush()?;
    }
    std::fs::rename(&tmp, path)
}
