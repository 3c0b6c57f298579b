//! Matrix Market (coordinate, real) reading and writing.
//!
//! Written files are `coordinate real general`, 1-based, in the component-major scalar
//! numbering (row `c n + i` is component c of vertex i), with values printed in Rust's
//! shortest round-trip form, so reading a written file gives the same bits back.
//! Reading accepts `real` or `integer` fields and `general` or `symmetric` symmetry.

use super::{Bsr3, SparseError};
use std::io::{BufRead, Write};

/// A matrix read from a Matrix Market file: size and scalar triplets (0-based).
#[derive(Clone, Debug, PartialEq)]
pub struct MatrixMarket {
    /// Rows.
    pub nrows: usize,
    /// Columns.
    pub ncols: usize,
    /// `(row, col, value)`, 0-based; symmetric files are expanded to both triangles.
    pub entries: Vec<(usize, usize, f64)>,
}

impl MatrixMarket {
    /// The matrix as a Bsr3 (square, size a multiple of 3).
    pub fn to_bsr3(&self, file: &str) -> Result<Bsr3, SparseError> {
        if self.nrows != self.ncols || !self.nrows.is_multiple_of(3) {
            return Err(SparseError::Parse {
                file: file.to_string(),
                line: 2,
                message: format!(
                    "a Bsr3 matrix must be square with a size divisible by 3, not {} x {}",
                    self.nrows, self.ncols
                ),
            });
        }
        Bsr3::from_triplets(self.nrows, &self.entries)
    }
}

/// Writes `a` as a Matrix Market coordinate file.
pub fn write_matrix_market(mut w: impl Write, a: &Bsr3) -> std::io::Result<()> {
    let size = 3 * a.n();
    writeln!(w, "%%MatrixMarket matrix coordinate real general")?;
    writeln!(
        w,
        "% largestep Bsr3, n = {} vertices; row c*n + i is component c of vertex i",
        a.n()
    )?;
    writeln!(w, "{size} {size} {}", 9 * a.pattern().nnz_blocks())?;
    let mut res = Ok(());
    a.for_each_entry(|r, c, v| {
        if res.is_ok() {
            res = writeln!(w, "{} {} {:?}", r + 1, c + 1, v);
        }
    });
    res
}

/// Reads a Matrix Market coordinate file; `file` names it in errors. Allocates in
/// proportion to what the reader holds, not to the sizes the file announces (read files
/// through [`crate::io::read_text`] to bound that too).
pub fn read_matrix_market(reader: impl BufRead, file: &str) -> Result<MatrixMarket, SparseError> {
    let err = |line: usize, message: String| SparseError::Parse {
        file: file.to_string(),
        line,
        message,
    };
    let mut lines = reader.lines().enumerate().map(|(i, l)| (i + 1, l));
    let next = |lines: &mut dyn Iterator<Item = (usize, std::io::Result<String>)>| -> Result<Option<(usize, String)>, SparseError> {
        match lines.next() {
            None => Ok(None),
            Some((ln, Ok(s))) => Ok(Some((ln, s))),
            Some((_, Err(e))) => Err(SparseError::Io {
                file: file.to_string(),
                source: e,
            }),
        }
    };
    let (ln, banner) = next(&mut lines)?.ok_or_else(|| err(1, "empty file".into()))?;
    let words: Vec<String> = banner
        .split_whitespace()
        .map(|w| w.to_ascii_lowercase())
        .collect();
    if words.len() != 5 || words[0] != "%%matrixmarket" || words[1] != "matrix" {
        return Err(err(ln, format!("expected the banner `%%MatrixMarket matrix coordinate real general`, found `{banner}`")));
    }
    if words[2] != "coordinate" {
        return Err(err(
            ln,
            format!("only `coordinate` format is supported, not `{}`", words[2]),
        ));
    }
    if words[3] != "real" && words[3] != "integer" {
        return Err(err(
            ln,
            format!(
                "only `real` or `integer` fields are supported, not `{}`",
                words[3]
            ),
        ));
    }
    let symmetric = match words[4].as_str() {
        "general" => false,
        "symmetric" => true,
        other => {
            return Err(err(
                ln,
                format!("only `general` or `symmetric` matrices are supported, not `{other}`"),
            ))
        }
    };
    let (ln, size) = loop {
        match next(&mut lines)? {
            None => {
                return Err(err(
                    ln + 1,
                    "missing the size line `rows cols entries`".into(),
                ))
            }
            Some((_, s)) if s.trim_start().starts_with('%') || s.trim().is_empty() => continue,
            Some(x) => break x,
        }
    };
    let nums: Vec<&str> = size.split_whitespace().collect();
    let parse_usize = |s: &str, what: &str, l: usize| {
        s.parse::<usize>().map_err(|_| {
            err(
                l,
                format!("expected {what} (a non-negative integer), found `{s}`"),
            )
        })
    };
    if nums.len() != 3 {
        return Err(err(
            ln,
            format!("expected `rows cols entries`, found `{size}`"),
        ));
    }
    let nrows = parse_usize(nums[0], "the row count", ln)?;
    let ncols = parse_usize(nums[1], "the column count", ln)?;
    let count = parse_usize(nums[2], "the entry count", ln)?;
    // The size line is only a claim: reserve for what it says up to a bound, and let the
    // entries actually read (as many as the reader holds) grow the rest.
    let announced = if symmetric {
        count.saturating_mul(2)
    } else {
        count
    };
    let mut entries = Vec::with_capacity(announced.min(1 << 16));
    let mut seen = 0usize;
    let mut last = ln;
    while let Some((l, s)) = next(&mut lines)? {
        last = l;
        let t = s.trim();
        if t.is_empty() || t.starts_with('%') {
            continue;
        }
        if seen == count {
            return Err(err(
                l,
                format!("more entries than the {count} the size line announces"),
            ));
        }
        let f: Vec<&str> = t.split_whitespace().collect();
        if f.len() != 3 {
            return Err(err(l, format!("expected `row col value`, found `{t}`")));
        }
        let r = parse_usize(f[0], "a row index", l)?;
        let c = parse_usize(f[1], "a column index", l)?;
        if r == 0 || r > nrows || c == 0 || c > ncols {
            return Err(err(
                l,
                format!(
                    "index ({r}, {c}) outside the {nrows} x {ncols} matrix (indices are 1-based)"
                ),
            ));
        }
        let v: f64 = f[2]
            .parse()
            .map_err(|_| err(l, format!("expected a number, found `{}`", f[2])))?;
        if !v.is_finite() {
            return Err(err(l, format!("value `{}` is not finite", f[2])));
        }
        entries.push((r - 1, c - 1, v));
        if symmetric && r != c {
            entries.push((c - 1, r - 1, v));
        }
        seen += 1;
    }
    if seen != count {
        return Err(err(
            last + 1,
            format!("file ends after {seen} of the {count} entries the size line announces"),
        ));
    }
    Ok(MatrixMarket {
        nrows,
        ncols,
        entries,
    })
}
