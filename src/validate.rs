//! Validation of model input: one error vocabulary ([`ModelError`]) and one pair of
//! helpers ([`check`], [`require`]) for every domain's builder and every shared service
//! (obstacles, loads).
//!
//! Errors name the item (`particle`, `spring`, `triangle`, `obstacle`, `wind`, ...), its
//! index among items of its kind, the field and the offending value, so that a scene can
//! locate them at the TOML key they came from (each domain's `scene.rs` maps them) and an
//! embedder can find the element in its own arrays.

/// Invalid model input, naming the item, its index and what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ModelError {
    /// A model needs at least one of these.
    #[error("the model has no {what}")]
    Empty {
        /// What is missing (`particles`).
        what: &'static str,
    },
    /// Array lengths disagree.
    #[error("{what} has {got} entries, expected {expected} (one per {per})")]
    Length {
        /// The array.
        what: &'static str,
        /// Its length.
        got: usize,
        /// The length expected.
        expected: usize,
        /// What each entry belongs to (`particle`, `vertex`).
        per: &'static str,
    },
    /// A value out of its range.
    #[error("{item} {index}: {field} = {value} is invalid ({why})")]
    Value {
        /// `particle`, `spring`, `vertex`, `material`, `gravity`, `obstacle`, `wind`, ...
        item: &'static str,
        /// Its index among items of its kind (the component for vectors).
        index: usize,
        /// The field.
        field: &'static str,
        /// The value.
        value: f64,
        /// What is expected.
        why: &'static str,
    },
    /// An item names a vertex (or particle) that does not exist.
    #[error("{item} {index} names {target} {named}, but there are only {n} {targets}")]
    Missing {
        /// `spring`, `triangle`, `pinned`.
        item: &'static str,
        /// Its index.
        index: usize,
        /// What it names (`particle`, `vertex`).
        target: &'static str,
        /// Plural of `target`.
        targets: &'static str,
        /// The index named.
        named: usize,
        /// How many exist.
        n: usize,
    },
    /// An element whose shape makes it unusable (a triangle of zero area, a spring from a
    /// particle to itself), with the reason.
    #[error("{item} {index} {what}")]
    Element {
        /// The element kind (`triangle`, `spring`).
        item: &'static str,
        /// Its index.
        index: usize,
        /// What is wrong with it.
        what: String,
    },
    /// Connectivity a model cannot use (an edge shared by three triangles), with the
    /// elements named.
    #[error("{0}")]
    Connectivity(String),
    /// The connectivity is too large to index.
    #[error("{0}")]
    TooLarge(String),
}

/// What a value must be.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rule {
    /// Finite.
    Finite,
    /// Finite and >= 0.
    NonNegative,
    /// Finite and > 0.
    Positive,
    /// A coordinate (m): finite and within [`MAX_COORDINATE`] of the origin, so that
    /// energies and distances computed from it stay finite.
    Coordinate,
}

/// The largest coordinate a model takes (m): 1e15 m, about 7,000 times the distance from
/// the Earth to the Sun. Beyond it `m g x` and squared distances lose all meaning (at
/// 1e308 they overflow), and nothing this library simulates is that large.
pub const MAX_COORDINATE: f64 = 1e15;

/// `Ok` if `value` obeys `rule`, else the error naming item, index and field.
pub fn check(
    item: &'static str,
    index: usize,
    field: &'static str,
    value: f64,
    rule: Rule,
) -> Result<(), ModelError> {
    let (ok, why) = match rule {
        Rule::Finite => (value.is_finite(), "must be finite"),
        Rule::NonNegative => (value.is_finite() && value >= 0.0, "must be finite and >= 0"),
        Rule::Positive => (value.is_finite() && value > 0.0, "must be finite and > 0"),
        Rule::Coordinate => (
            value.abs() <= MAX_COORDINATE,
            "must be finite and within 1e15 m of the origin",
        ),
    };
    require(item, index, field, value, ok, why)
}

/// `Ok` when every vertex element `index` (an `item`: `triangle`, `tetrahedron`) names
/// is below `n`, else the error naming the first one that is not.
pub fn vertices_exist(
    item: &'static str,
    index: usize,
    vertices: &[u32],
    n: usize,
) -> Result<(), ModelError> {
    match vertices.iter().find(|&&v| v as usize >= n) {
        None => Ok(()),
        Some(&v) => Err(ModelError::Missing {
            item,
            index,
            target: "vertex",
            targets: "vertices",
            named: v as usize,
            n,
        }),
    }
}

/// `Ok` if `ok`, else the error naming item, index, field and `why`.
pub fn require(
    item: &'static str,
    index: usize,
    field: &'static str,
    value: f64,
    ok: bool,
    why: &'static str,
) -> Result<(), ModelError> {
    if ok {
        Ok(())
    } else {
        Err(ModelError::Value {
            item,
            index,
            field,
            value,
            why,
        })
    }
}
