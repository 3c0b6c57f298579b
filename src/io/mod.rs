//! File output: meshes (OBJ, PLY) and the atomic write every output goes through.
//!
//! Files are written to `NAME.tmp` and renamed into place, so a reader (or a run that
//! fails later) never sees half a file: what was written before an error stays valid.

mod mesh;

pub use mesh::{
    parse_obj, parse_obj_uv, read_obj, read_obj_uv, write_obj, write_ply, Mesh, MeshRef, ReadError,
};
mod image;
pub use image::{read_png, write_gif, write_png, Image};

use std::io::{BufWriter, Write};
use std::path::Path;

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
