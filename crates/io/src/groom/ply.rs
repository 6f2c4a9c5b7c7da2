//! PLY: a generic element/property parser shared by the strand reader here
//! and the mesh reader (`crate::mesh`), plus the strand layout hairutil
//! writes with hapPLY:
//!
//! ```text
//! element vertex N    property float x, y, z; property uchar red, green, blue
//!                     [property float thickness]     (hairutil's name for cyHair thickness)
//! element strand S    property ushort nsegs          (strand i has nsegs+1 points)
//! element edge E      property int vertex1, vertex2  (E = N - S polyline edges)
//! ```
//!
//! Strands are consecutive runs of vertices. The reader finds the runs from,
//! in order of preference: a `strand` element with a per-strand count
//! (`nsegs` = points - 1, or `nverts`/`npoints`/`count` = points); a
//! per-vertex strand id (`strand_id`, `strand`, `hair_id`, `curve_id`),
//! where a change of id starts a new strand; the `edge` element, where a
//! missing `(i, i+1)` edge starts a new strand.

use std::io::Write;
use std::path::Path;

use super::{checked, validate_for, Groom, Strand};
use crate::bytes::{corrupt, read_file, unsupported, Reader};
use crate::{Error, ErrorKind};

/// How the PLY body is encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Encoding {
    Ascii,
    BinaryLe,
    BinaryBe,
}

/// PLY scalar types, with both the classic and the sized spellings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// Decodes one value from exactly `self.size()` bytes.
    fn decode(self, b: &[u8], big_endian: bool) -> f64 {
        macro_rules! num {
            ($t:ty, $n:expr) => {{
                let mut a = [0u8; $n];
                a.copy_from_slice(&b[..$n]);
                if big_endian {
                    <$t>::from_be_bytes(a) as f64
                } else {
                    <$t>::from_le_bytes(a) as f64
                }
            }};
        }
        match self {
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => num!(i16, 2),
            Scalar::U16 => num!(u16, 2),
            Scalar::I32 => num!(i32, 4),
            Scalar::U32 => num!(u32, 4),
            Scalar::F32 => num!(f32, 4),
            Scalar::F64 => num!(f64, 8),
        }
    }
}

/// A property declaration from the header.
#[derive(Clone, Debug)]
pub(crate) enum PropKind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

/// One `property` line.
#[derive(Clone, Debug)]
pub(crate) struct PropDef {
    pub name: String,
    pub kind: PropKind,
}

/// One `element` line and its properties.
#[derive(Clone, Debug)]
pub(crate) struct ElementDef {
    pub name: String,
    pub count: usize,
    pub props: Vec<PropDef>,
}

/// Values of one decoded property, widened to `f64` (exact for every PLY
/// type up to 32-bit integers and doubles).
#[derive(Clone, Debug, Default)]
pub(crate) enum Column {
    /// Property not requested: skipped by its type size.
    #[default]
    Skipped,
    Scalar(Vec<f64>),
    /// Record `i` owns `values[offsets[i]..offsets[i + 1]]`.
    List {
        offsets: Vec<usize>,
        values: Vec<f64>,
    },
}

/// A decoded element.
#[derive(Clone, Debug)]
pub(crate) struct Element {
    pub def: ElementDef,
    pub columns: Vec<Column>,
}

impl Element {
    /// The scalar column named `name`, if declared scalar and decoded.
    pub fn scalar(&self, name: &str) -> Option<&[f64]> {
        let i = self.def.props.iter().position(|p| p.name == name)?;
        match &self.columns[i] {
            Column::Scalar(v) => Some(v),
            _ => None,
        }
    }

    /// The first decoded scalar column among `names`.
    pub fn scalar_any(&self, names: &[&str]) -> Option<&[f64]> {
        names.iter().find_map(|n| self.scalar(n))
    }

    /// The list column named `name`, as `(offsets, values)`.
    pub fn list(&self, name: &str) -> Option<(&[usize], &[f64])> {
        let i = self.def.props.iter().position(|p| p.name == name)?;
        match &self.columns[i] {
            Column::List { offsets, values } => Some((offsets, values)),
            _ => None,
        }
    }
}

/// A decoded PLY file: header facts plus the requested columns.
#[derive(Clone, Debug)]
pub(crate) struct PlyData {
    pub elements: Vec<Element>,
}

impl PlyData {
    /// The element named `name`.
    pub fn element(&self, name: &str) -> Option<&Element> {
        self.elements.iter().find(|e| e.def.name == name)
    }
}

fn parse_header(bytes: &[u8]) -> Result<(Encoding, Vec<ElementDef>, usize), ErrorKind> {
    if !bytes.starts_with(b"ply\n") && !bytes.starts_with(b"ply\r\n") {
        return Err(corrupt("not a PLY file (no 'ply' magic line)"));
    }
    let mut pos = 0;
    let mut encoding = None;
    let mut elements: Vec<ElementDef> = Vec::new();
    loop {
        let rest = &bytes[pos..];
        let Some(nl) = rest.iter().position(|&b| b == b'\n') else {
            return Err(ErrorKind::Truncated { what: "PLY header (no end_header line)", offset: pos, needed: 1 });
        };
        let line_bytes = &rest[..nl];
        let line_no = pos;
        pos += nl + 1;
        let line = std::str::from_utf8(line_bytes)
            .map_err(|_| corrupt(format!("PLY header line at byte {line_no} is not text")))?
            .trim();
        let mut words = line.split_ascii_whitespace();
        match words.next() {
            Some("ply") | Some("comment") | Some("obj_info") | None => {}
            Some("end_header") => break,
            Some("format") => {
                encoding = Some(match words.next() {
                    Some("ascii") => Encoding::Ascii,
                    Some("binary_little_endian") => Encoding::BinaryLe,
                    Some("binary_big_endian") => Encoding::BinaryBe,
                    other => return Err(corrupt(format!("unknown PLY format {other:?}"))),
                });
            }
            Some("element") => {
                let (Some(name), Some(count), None) = (words.next(), words.next(), words.next()) else {
                    return Err(corrupt(format!("bad PLY element line '{line}'")));
                };
                let count: usize = count.parse().map_err(|_| corrupt(format!("bad PLY element count in '{line}'")))?;
                elements.push(ElementDef { name: name.to_string(), count, props: Vec::new() });
            }
            Some("property") => {
                let Some(el) = elements.last_mut() else {
                    return Err(corrupt(format!("PLY property before any element: '{line}'")));
                };
                let w: Vec<&str> = words.collect();
                let ty =
                    |s: &str| Scalar::parse(s).ok_or_else(|| corrupt(format!("unknown PLY type '{s}' in '{line}'")));
                let (kind, name) = match w.as_slice() {
                    ["list", c, i, name] => {
                        let count = ty(c)?;
                        if !count.is_integer() {
                            return Err(corrupt(format!("PLY list count must be an integer type: '{line}'")));
                        }
                        (PropKind::List { count, item: ty(i)? }, name)
                    }
                    [t, name] => (PropKind::Scalar(ty(t)?), name),
                    _ => return Err(corrupt(format!("bad PLY property line '{line}'"))),
                };
                el.props.push(PropDef { name: name.to_string(), kind });
            }
            Some(other) => return Err(corrupt(format!("unknown PLY header keyword '{other}'"))),
        }
    }
    let encoding = encoding.ok_or_else(|| corrupt("PLY header has no format line"))?;
    Ok((encoding, elements, pos))
}

/// Parses a PLY file, decoding only the properties for which
/// `wanted(element, property)` is true; the rest are skipped by type size.
pub(crate) fn parse_ply(bytes: &[u8], wanted: &dyn Fn(&str, &str) -> bool) -> Result<PlyData, ErrorKind> {
    let (encoding, defs, body) = parse_header(bytes)?;
    let mut elements = Vec::with_capacity(defs.len());
    match encoding {
        Encoding::Ascii => {
            let mut tokens = AsciiTokens { bytes, pos: body };
            for def in defs {
                let el = read_ascii_element(&mut tokens, def, wanted)?;
                elements.push(el);
            }
        }
        Encoding::BinaryLe | Encoding::BinaryBe => {
            let big = encoding == Encoding::BinaryBe;
            let mut pos = body;
            for def in defs {
                let el = read_binary_element(bytes, &mut pos, def, big, wanted)?;
                elements.push(el);
            }
        }
    }
    Ok(PlyData { elements })
}

fn new_columns(def: &ElementDef, wanted: &dyn Fn(&str, &str) -> bool, cap: usize) -> Vec<Column> {
    def.props
        .iter()
        .map(|p| {
            if !wanted(&def.name, &p.name) {
                Column::Skipped
            } else {
                match p.kind {
                    PropKind::Scalar(_) => Column::Scalar(Vec::with_capacity(cap)),
                    PropKind::List { .. } => Column::List {
                        offsets: {
                            let mut o = Vec::with_capacity(cap + 1);
                            o.push(0);
                            o
                        },
                        values: Vec::new(),
                    },
                }
            }
        })
        .collect()
}

fn read_binary_element(
    bytes: &[u8],
    pos: &mut usize,
    def: ElementDef,
    big: bool,
    wanted: &dyn Fn(&str, &str) -> bool,
) -> Result<Element, ErrorKind> {
    // Lower bound of one record, to refuse absurd counts before allocating.
    let min_record: usize = def
        .props
        .iter()
        .map(|p| match p.kind {
            PropKind::Scalar(t) => t.size(),
            PropKind::List { count, .. } => count.size(),
        })
        .sum();
    let remaining = bytes.len().saturating_sub(*pos);
    if (def.count as u128) * (min_record as u128) > remaining as u128 {
        return Err(ErrorKind::Truncated {
            what: "PLY element data",
            offset: *pos,
            needed: (def.count as u128 * min_record as u128 - remaining as u128).min(usize::MAX as u128) as usize,
        });
    }
    let count = if min_record == 0 { 0 } else { def.count };
    let mut columns = new_columns(&def, wanted, count);
    const WHAT: &str = "PLY element data";
    let mut r = Reader::new(bytes, *pos);
    for _ in 0..count {
        for (p, col) in def.props.iter().zip(columns.iter_mut()) {
            match (&p.kind, col) {
                (PropKind::Scalar(t), Column::Scalar(v)) => v.push(t.decode(r.take(t.size(), WHAT)?, big)),
                (PropKind::Scalar(t), _) => {
                    r.take(t.size(), WHAT)?;
                }
                (PropKind::List { count, item }, col) => {
                    let n = count.decode(r.take(count.size(), WHAT)?, big);
                    if !(0.0..=u32::MAX as f64).contains(&n) {
                        return Err(corrupt(format!("PLY list length {n} in element '{}'", def.name)));
                    }
                    let raw = r.take(n as usize * item.size(), WHAT)?;
                    if let Column::List { offsets, values } = col {
                        values.extend(raw.chunks_exact(item.size()).map(|b| item.decode(b, big)));
                        offsets.push(values.len());
                    }
                }
            }
        }
    }
    *pos = r.pos();
    Ok(Element { def, columns })
}

/// Whitespace-separated tokens of an ASCII PLY body.
struct AsciiTokens<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl AsciiTokens<'_> {
    fn next_number(&mut self, element: &str) -> Result<f64, ErrorKind> {
        let b = self.bytes;
        while self.pos < b.len() && b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        let start = self.pos;
        while self.pos < b.len() && !b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        if start == self.pos {
            return Err(ErrorKind::Truncated { what: "ASCII PLY element data", offset: start, needed: 1 });
        }
        std::str::from_utf8(&b[start..self.pos])
            .ok()
            .and_then(|s| s.parse::<f64>().ok())
            .ok_or_else(|| corrupt(format!("bad number at byte {start} in PLY element '{element}'")))
    }
}

fn read_ascii_element(
    t: &mut AsciiTokens,
    def: ElementDef,
    wanted: &dyn Fn(&str, &str) -> bool,
) -> Result<Element, ErrorKind> {
    // Every value takes at least two bytes (digit + separator).
    let remaining = t.bytes.len().saturating_sub(t.pos);
    if !def.props.is_empty() && (def.count as u128) * (def.props.len() as u128) > remaining as u128 / 2 + 1 {
        return Err(ErrorKind::Truncated {
            what: "ASCII PLY element data",
            offset: t.pos,
            needed: def.count.saturating_mul(def.props.len()).saturating_mul(2) - remaining,
        });
    }
    let count = if def.props.is_empty() { 0 } else { def.count };
    let mut columns = new_columns(&def, wanted, count);
    for _ in 0..count {
        for (p, col) in def.props.iter().zip(columns.iter_mut()) {
            match (&p.kind, col) {
                (PropKind::Scalar(_), col) => {
                    let x = t.next_number(&def.name)?;
                    if let Column::Scalar(v) = col {
                        v.push(x);
                    }
                }
                (PropKind::List { .. }, col) => {
                    let n = t.next_number(&def.name)?;
                    if !(0.0..=(t.bytes.len() as f64)).contains(&n) || n.fract() != 0.0 {
                        return Err(corrupt(format!("PLY list length {n} in element '{}'", def.name)));
                    }
                    for _ in 0..n as usize {
                        let x = t.next_number(&def.name)?;
                        if let Column::List { values, .. } = col {
                            values.push(x);
                        }
                    }
                    if let Column::List { offsets, values } = col {
                        offsets.push(values.len());
                    }
                }
            }
        }
    }
    Ok(Element { def, columns })
}

/// Reads strands from a PLY file (ascii or binary, either endianness);
/// `red`/`green`/`blue` vertex properties become [`Strand::colors`]
/// (divided by 255 when stored as `uchar`), and a `thickness` (hairutil,
/// and what [`write_ply_strands`] writes) or `width` vertex property
/// [`Strand::widths`].
pub fn read_ply_strands(path: &Path) -> Result<Groom, Error> {
    let bytes = read_file(path)?;
    read_ply_strands_bytes(path, &bytes)
}

/// [`read_ply_strands`] on bytes in memory; `path` only names them in errors.
pub fn read_ply_strands_bytes(path: &Path, bytes: &[u8]) -> Result<Groom, Error> {
    checked(path, parse_strands(bytes))
}

const STRAND_ELEMENTS: [&str; 3] = ["strand", "strands", "curve"];
const SEGMENT_COUNTS: [&str; 1] = ["nsegs"];
const POINT_COUNTS: [&str; 5] = ["nverts", "nvertices", "npoints", "vertex_count", "count"];
const STRAND_IDS: [&str; 4] = ["strand_id", "strand", "hair_id", "curve_id"];
const WIDTHS: [&str; 2] = ["thickness", "width"];

fn parse_strands(bytes: &[u8]) -> Result<Groom, ErrorKind> {
    let ply = parse_ply(bytes, &|el, prop| match el {
        "vertex" => {
            matches!(prop, "x" | "y" | "z" | "red" | "green" | "blue")
                || STRAND_IDS.contains(&prop)
                || WIDTHS.contains(&prop)
        }
        "edge" => matches!(prop, "vertex1" | "vertex2"),
        e if STRAND_ELEMENTS.contains(&e) => SEGMENT_COUNTS.contains(&prop) || POINT_COUNTS.contains(&prop),
        _ => false,
    })?;
    let vertex = ply.element("vertex").ok_or_else(|| corrupt("PLY has no 'vertex' element"))?;
    let (Some(x), Some(y), Some(z)) = (vertex.scalar("x"), vertex.scalar("y"), vertex.scalar("z")) else {
        return Err(corrupt("PLY vertex element lacks scalar x, y, z"));
    };
    let n = x.len();
    let points: Vec<[f32; 3]> = (0..n).map(|i| [x[i] as f32, y[i] as f32, z[i] as f32]).collect();
    let colors = match (vertex.scalar("red"), vertex.scalar("green"), vertex.scalar("blue")) {
        (Some(r), Some(g), Some(b)) => {
            let uchar =
                vertex.def.props.iter().any(|p| p.name == "red" && matches!(p.kind, PropKind::Scalar(Scalar::U8)));
            let c = |x: f64| if uchar { byte_color(x as u8) } else { x as f32 };
            Some((0..n).map(|i| [c(r[i]), c(g[i]), c(b[i])]).collect::<Vec<_>>())
        }
        _ => None,
    };
    let widths: Option<Vec<f32>> = vertex.scalar_any(&WIDTHS).map(|w| w.iter().map(|&x| x as f32).collect());
    let lengths = strand_lengths(&ply, vertex, n)?;
    let mut strands = Vec::with_capacity(lengths.len());
    let mut start = 0;
    for len in lengths {
        let end = start + len;
        strands.push(Strand {
            points: points[start..end].to_vec(),
            widths: widths.as_ref().map(|w| w[start..end].to_vec()),
            colors: colors.as_ref().map(|c| c[start..end].to_vec()),
        });
        start = end;
    }
    Ok(Groom { strands })
}

/// The scalar property `name` of a strand PLY, one value per strand: the
/// strand element's own, or else the vertex element's at each strand's
/// root (a style map painted on the strands or carried to their roots).
pub fn read_ply_strand_attribute(path: &Path, name: &str) -> Result<Vec<f32>, Error> {
    let bytes = read_file(path)?;
    parse_strand_attribute(&bytes, name).map_err(Error::at(path))
}

fn parse_strand_attribute(bytes: &[u8], name: &str) -> Result<Vec<f32>, ErrorKind> {
    let ply = parse_ply(bytes, &|el, prop| {
        prop == name
            || match el {
                "vertex" => matches!(prop, "x") || STRAND_IDS.contains(&prop),
                "edge" => matches!(prop, "vertex1" | "vertex2"),
                e if STRAND_ELEMENTS.contains(&e) => SEGMENT_COUNTS.contains(&prop) || POINT_COUNTS.contains(&prop),
                _ => false,
            }
    })?;
    if let Some(v) = STRAND_ELEMENTS.iter().find_map(|e| ply.element(e)).and_then(|el| el.scalar(name)) {
        return Ok(v.iter().map(|&x| x as f32).collect());
    }
    let vertex = ply.element("vertex").ok_or_else(|| corrupt("PLY has no 'vertex' element"))?;
    let Some(values) = vertex.scalar(name) else {
        return Err(corrupt(format!("PLY has no scalar strand or vertex property '{name}'")));
    };
    let lengths = strand_lengths(&ply, vertex, values.len())?;
    let mut root = 0;
    Ok(lengths
        .iter()
        .map(|&len| {
            let v = values[root] as f32;
            root += len;
            v
        })
        .collect())
}

/// Points per strand, from whichever delimiter the file has (module notes).
fn strand_lengths(ply: &PlyData, vertex: &Element, n: usize) -> Result<Vec<usize>, ErrorKind> {
    let strand_el = STRAND_ELEMENTS.iter().find_map(|name| ply.element(name));
    if let Some(el) = strand_el {
        let (counts, extra) = if let Some(c) = el.scalar_any(&SEGMENT_COUNTS) {
            (c, 1)
        } else if let Some(c) = el.scalar_any(&POINT_COUNTS) {
            (c, 0)
        } else {
            return Err(unsupported(format!(
                "PLY element '{}' has no per-strand count (nsegs, nverts, npoints, vertex_count, count)",
                el.def.name
            )));
        };
        let mut lengths = Vec::with_capacity(counts.len());
        let mut total = 0usize;
        for (i, &c) in counts.iter().enumerate() {
            if c < 0.0 || c.fract() != 0.0 || c > n as f64 {
                return Err(corrupt(format!("strand {i} has bad count {c}")));
            }
            let len = c as usize + extra;
            total += len;
            lengths.push(len);
        }
        if total != n {
            return Err(corrupt(format!("strand counts add up to {total} points, vertex element has {n}")));
        }
        return Ok(lengths);
    }
    if let Some(ids) = vertex.scalar_any(&STRAND_IDS) {
        return Ok(runs(n, |i| ids[i] != ids[i - 1]));
    }
    if let Some(edge) = ply.element("edge") {
        if let (Some(a), Some(b)) = (edge.scalar("vertex1"), edge.scalar("vertex2")) {
            let mut linked = vec![false; n];
            for (&a, &b) in a.iter().zip(b) {
                let (lo, hi) = (a.min(b), a.max(b));
                if lo >= 0.0 && hi - lo == 1.0 && (hi as usize) < n {
                    linked[hi as usize] = true;
                }
            }
            return Ok(runs(n, |i| !linked[i]));
        }
    }
    Err(unsupported("cannot tell how strands are delimited (no strand element, strand id or edge element)"))
}

/// Lengths of consecutive runs of `0..n`, a new run starting at `i > 0`
/// wherever `starts(i)`.
fn runs(n: usize, starts: impl Fn(usize) -> bool) -> Vec<usize> {
    let mut lengths = Vec::new();
    let mut start = 0;
    for i in 1..=n {
        if i == n || starts(i) {
            lengths.push(i - start);
            start = i;
        }
    }
    lengths
}

/// Writes `groom` as a binary little-endian PLY in hairutil's hapPLY layout
/// (module notes), so tools that read the shared Bangs file read ours.
/// Colours are written from [`Strand::colors`] as `uchar`s (white where a
/// strand has none): colours read from a `uchar` PLY come back as the same
/// bytes, finer ones (cyHair, USD) are rounded to the nearest 1/255. Widths
/// are written as hairutil's `float thickness` when every strand has them,
/// exactly. Fails if a strand has more than 65536 points (`nsegs` is a
/// `ushort`).
pub fn write_ply_strands(path: &Path, groom: &Groom) -> Result<(), Error> {
    let werr = |reason: String| {
        Error::new(path, ErrorKind::Write(std::io::Error::new(std::io::ErrorKind::InvalidInput, reason)))
    };
    validate_for(groom, path)?;
    if let Some(i) = groom.strands.iter().position(|s| s.points.len() - 1 > u16::MAX as usize) {
        return Err(werr(format!(
            "strand {i} has {} points; the PLY strand layout stores nsegs as ushort (max 65536 points)",
            groom.strands[i].points.len()
        )));
    }
    let n = groom.point_count();
    if n > i32::MAX as usize {
        return Err(werr(format!("{n} points do not fit PLY int edge indices")));
    }
    let edges = n - groom.strand_count();
    let widths = groom.strands.iter().all(|s| s.widths.is_some());
    let mut body = Vec::with_capacity(n * 19 + groom.strand_count() * 2 + edges * 8 + 400);
    write!(
        body,
        "ply\nformat binary_little_endian 1.0\ncomment Written by nst3d (hapPLY strand layout)\n\
         element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n{}\
         element strand {}\nproperty ushort nsegs\n\
         element edge {edges}\nproperty int vertex1\nproperty int vertex2\nend_header\n",
        if widths { "property float thickness\n" } else { "" },
        groom.strand_count()
    )
    .expect("writing to a Vec cannot fail");
    for s in &groom.strands {
        for (j, p) in s.points.iter().enumerate() {
            for c in p {
                body.extend_from_slice(&c.to_le_bytes());
            }
            let rgb = s.colors.as_ref().map_or([1.0; 3], |c| c[j]);
            body.extend(rgb.iter().map(|&c| color_byte(c)));
            if let Some(w) = s.widths.as_ref().filter(|_| widths) {
                body.extend_from_slice(&w[j].to_le_bytes());
            }
        }
    }
    for s in &groom.strands {
        body.extend_from_slice(&((s.points.len() - 1) as u16).to_le_bytes());
    }
    let mut start = 0i32;
    for s in &groom.strands {
        for j in 0..s.points.len() as i32 - 1 {
            body.extend_from_slice(&(start + j).to_le_bytes());
            body.extend_from_slice(&(start + j + 1).to_le_bytes());
        }
        start += s.points.len() as i32;
    }
    crate::atomic::write_atomic(path, |w| w.write_all(&body)).map_err(|e| Error::new(path, ErrorKind::Write(e)))
}

/// The `uchar` a colour channel is written as: the nearest of `k / 255`,
/// so a channel read from a `uchar` PLY (`k as f64 / 255`, to `f32`) gives
/// back its byte `k`.
pub(crate) fn color_byte(c: f32) -> u8 {
    (c.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// The colour channel the reader makes of a `uchar` PLY byte.
pub(crate) fn byte_color(k: u8) -> f32 {
    (k as f64 * (1.0 / 255.0)) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    const TWO_STRANDS: &str = "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\n\
        property float z\nproperty float region\nelement strand 2\nproperty ushort nsegs\nproperty float side\n\
        end_header\n0 0 0 0.25\n0 1 0 9\n1 0 0 0.75\n1 1 0 9\n1 2 0 9\n1 0.5\n2 1\n";

    #[test]
    fn a_strand_attribute_is_the_strands_own_or_the_roots() {
        assert_eq!(parse_strand_attribute(TWO_STRANDS.as_bytes(), "side").unwrap(), vec![0.5, 1.0]);
        assert_eq!(parse_strand_attribute(TWO_STRANDS.as_bytes(), "region").unwrap(), vec![0.25, 0.75]);
        let e = parse_strand_attribute(TWO_STRANDS.as_bytes(), "age").unwrap_err().to_string();
        assert!(e.contains("no scalar strand or vertex property 'age'"), "{e}");
    }

    #[test]
    fn every_colour_byte_survives_read_then_write() {
        for k in 0..=255u8 {
            assert_eq!(color_byte(byte_color(k)), k);
        }
    }
}
