//! What a crate file holds, as the reader returns it and the writer takes
//! it: specs (a path, a kind, named fields) whose field values are
//! [`Value`]s. Numbers keep their stored element type, so a `half` or an
//! `int64` primvar is written back as what it was; text types (string,
//! token, asset path) keep theirs.

/// The scalar type of a numeric value's components.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Comp {
    Bool,
    UChar,
    Int,
    UInt,
    Int64,
    UInt64,
    Half,
    Float,
    Double,
}

impl Comp {
    /// Bytes of one component in the file.
    pub(crate) fn size(self) -> usize {
        match self {
            Comp::Bool | Comp::UChar => 1,
            Comp::Half => 2,
            Comp::Int | Comp::UInt | Comp::Float => 4,
            Comp::Int64 | Comp::UInt64 | Comp::Double => 8,
        }
    }

    pub(crate) fn is_float(self) -> bool {
        matches!(self, Comp::Half | Comp::Float | Comp::Double)
    }
}

/// How many components an element has and how they are arranged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Shape {
    Scalar,
    /// A time code: one double, its own type.
    TimeCode,
    /// `n` components, 2 to 4.
    Vec(usize),
    /// Stored imaginary part first, real part last (written real first in text).
    Quat,
    /// `n`×`n`, row by row.
    Matrix(usize),
}

impl Shape {
    pub(crate) fn components(self) -> usize {
        match self {
            Shape::Scalar | Shape::TimeCode => 1,
            Shape::Vec(n) => n,
            Shape::Quat => 4,
            Shape::Matrix(n) => n * n,
        }
    }
}

/// A numeric element type: component type and shape.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct NumType {
    pub(crate) comp: Comp,
    pub(crate) shape: Shape,
}

/// Type codes of the crate's value representations (the format's type
/// enum) for the numeric types, both ways.
const NUM_CODES: [(u8, Comp, Shape); 28] = [
    (1, Comp::Bool, Shape::Scalar),
    (2, Comp::UChar, Shape::Scalar),
    (3, Comp::Int, Shape::Scalar),
    (4, Comp::UInt, Shape::Scalar),
    (5, Comp::Int64, Shape::Scalar),
    (6, Comp::UInt64, Shape::Scalar),
    (7, Comp::Half, Shape::Scalar),
    (8, Comp::Float, Shape::Scalar),
    (9, Comp::Double, Shape::Scalar),
    (13, Comp::Double, Shape::Matrix(2)),
    (14, Comp::Double, Shape::Matrix(3)),
    (15, Comp::Double, Shape::Matrix(4)),
    (16, Comp::Double, Shape::Quat),
    (17, Comp::Float, Shape::Quat),
    (18, Comp::Half, Shape::Quat),
    (19, Comp::Double, Shape::Vec(2)),
    (20, Comp::Float, Shape::Vec(2)),
    (21, Comp::Half, Shape::Vec(2)),
    (22, Comp::Int, Shape::Vec(2)),
    (23, Comp::Double, Shape::Vec(3)),
    (24, Comp::Float, Shape::Vec(3)),
    (25, Comp::Half, Shape::Vec(3)),
    (26, Comp::Int, Shape::Vec(3)),
    (27, Comp::Double, Shape::Vec(4)),
    (28, Comp::Float, Shape::Vec(4)),
    (29, Comp::Half, Shape::Vec(4)),
    (30, Comp::Int, Shape::Vec(4)),
    (56, Comp::Double, Shape::TimeCode),
];

impl NumType {
    /// The numeric type of a type code.
    pub(crate) fn of_code(code: u8) -> Option<NumType> {
        NUM_CODES.iter().find(|c| c.0 == code).map(|&(_, comp, shape)| NumType { comp, shape })
    }

    /// The type code of a numeric type.
    pub(crate) fn code(self) -> u8 {
        NUM_CODES.iter().find(|c| c.1 == self.comp && c.2 == self.shape).map_or(0, |c| c.0)
    }

    pub(crate) fn scalar(comp: Comp) -> NumType {
        NumType { comp, shape: Shape::Scalar }
    }
}

/// Type codes of the text and structural types the reader and writer use.
pub(crate) mod code {
    pub(crate) const STRING: u8 = 10;
    pub(crate) const TOKEN: u8 = 11;
    pub(crate) const ASSET: u8 = 12;
    pub(crate) const DICTIONARY: u8 = 31;
    pub(crate) const REFERENCE_LIST_OP: u8 = 35;
    pub(crate) const PATH_VECTOR: u8 = 40;
    pub(crate) const TOKEN_VECTOR: u8 = 41;
    pub(crate) const SPECIFIER: u8 = 42;
    pub(crate) const VARIABILITY: u8 = 44;
    pub(crate) const TIME_SAMPLES: u8 = 46;
    pub(crate) const PAYLOAD: u8 = 47;
    pub(crate) const DOUBLE_VECTOR: u8 = 48;
    pub(crate) const STRING_VECTOR: u8 = 50;
    pub(crate) const VALUE_BLOCK: u8 = 51;
    pub(crate) const VALUE: u8 = 52;
    pub(crate) const PAYLOAD_LIST_OP: u8 = 55;
}

/// Numbers of one numeric value, flattened (components of each element in
/// order): floating types as `f64` (exact for half and float), the signed
/// and small types as `i64`, `uint64` as `u64`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Nums {
    F(Vec<f64>),
    I(Vec<i64>),
    U(Vec<u64>),
}

impl Nums {
    pub(crate) fn len(&self) -> usize {
        match self {
            Nums::F(v) => v.len(),
            Nums::I(v) => v.len(),
            Nums::U(v) => v.len(),
        }
    }
}

/// Which text type a string value is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum TextKind {
    String,
    Token,
    Asset,
}

impl TextKind {
    pub(crate) fn code(self) -> u8 {
        match self {
            TextKind::String => code::STRING,
            TextKind::Token => code::TOKEN,
            TextKind::Asset => code::ASSET,
        }
    }
}

/// A reference or payload arc: the layer (empty: this one) and the prim
/// (empty: the layer's default prim).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Arc {
    pub(crate) asset: String,
    pub(crate) prim: String,
}

/// One field value.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Value {
    /// A number, vector, quaternion or matrix, or an array of them.
    Num { ty: NumType, array: bool, nums: Nums },
    /// A string, token or asset path, or an array of them.
    Text { kind: TextKind, array: bool, items: Vec<String> },
    /// A list of tokens (`primChildren`, `properties`, `xformOpOrder`
    /// stored as a token vector).
    Tokens(Vec<String>),
    /// A list of strings (`subLayers`).
    Strings(Vec<String>),
    /// A list of paths, as text.
    Paths(Vec<String>),
    /// Time sample times.
    Doubles(Vec<f64>),
    /// `def` (0), `over` (1) or `class` (2).
    Specifier(u32),
    /// `varying` (0) or `uniform` (1).
    Variability(u32),
    /// References or payloads: the items that add arcs (explicit, added,
    /// prepended and appended; deletions and orderings are not kept).
    Arcs(Vec<Arc>),
    /// A dictionary (`customData`): keys and values.
    Dict(Vec<(String, Value)>),
    /// Time samples: (time, value) in file order.
    Samples(Vec<(f64, Value)>),
    /// An explicitly blocked value (`None` in text).
    Block,
    /// A value of a type this reader does not decode (its type code).
    Other(u8),
}

impl Value {
    /// The token of a `Text` value that is one token or string.
    pub(crate) fn as_text(&self) -> Option<&str> {
        match self {
            Value::Text { array: false, items, .. } => items.first().map(String::as_str),
            _ => None,
        }
    }
}

/// What a spec is (the format's spec type enum; only these are read).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum SpecKind {
    Attribute,
    Prim,
    PseudoRoot,
    Relationship,
    /// Connections, variants, variant sets and others the groom reader skips.
    Other(u32),
}

impl SpecKind {
    pub(crate) fn of_code(c: u32) -> SpecKind {
        match c {
            1 => SpecKind::Attribute,
            6 => SpecKind::Prim,
            7 => SpecKind::PseudoRoot,
            8 => SpecKind::Relationship,
            other => SpecKind::Other(other),
        }
    }

    pub(crate) fn code(self) -> u32 {
        match self {
            SpecKind::Attribute => 1,
            SpecKind::Prim => 6,
            SpecKind::PseudoRoot => 7,
            SpecKind::Relationship => 8,
            SpecKind::Other(c) => c,
        }
    }
}

/// One spec: its path (`/`, `/A/B` or `/A/B.attr`), kind and fields.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Spec {
    pub(crate) path: String,
    pub(crate) kind: SpecKind,
    pub(crate) fields: Vec<(String, Value)>,
}
