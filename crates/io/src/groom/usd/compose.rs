//! Composition, as far as a groom needs it: the root layer's sublayers
//! (weaker layers whose prims merge under the root's) and every prim's
//! references and payloads (the target prim's attributes and children
//! merged under the referencing prim as weaker opinions), to any depth up
//! to [`MAX_DEPTH`]. Merging is per prim and per attribute statement: the
//! stronger side's specifier (unless it only says `over`), type,
//! `active` and attributes win, children with the same name merge. Not
//! done: list editing beyond adding arcs, layer offsets, variants,
//! inherits and specializes.
//!
//! Layers come from a file next to the layer that names them (when the
//! caller allows files) or from the `.usdz` package the layer is in; a
//! layer may be text, a crate file or a package (its first file). An arc
//! that cannot be followed (a missing file, an unknown prim) is a note,
//! not an error: a scene's other assets need not be there for its groom
//! to be read.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use crate::bytes::{corrupt, unsupported};
use crate::groom::usda::parse::{self, Prim, Val};
use crate::groom::{usdc, usdz};
use crate::ErrorKind;

/// Deepest chain of sublayers and arcs followed (cycles end here).
pub(super) const MAX_DEPTH: usize = 16;

/// Most layers one stage may load.
const MAX_LAYERS: usize = 256;

/// Most notes kept about arcs not followed.
const MAX_NOTES: usize = 16;

/// Where the readers look for the layers a USD layer points to
/// (sublayers, references, payloads).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UsdAssets {
    /// Files relative to the folder of the layer that names them, and the
    /// files inside a `.usdz` package.
    Files,
    /// Only the files inside a `.usdz` package: nothing else is read.
    PackageOnly,
}

/// Where a layer is.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
enum Location {
    File(PathBuf),
    /// A file inside package `package` (an index into [`Stage::packages`]).
    Packaged {
        package: usize,
        inner: String,
    },
}

/// One loaded layer: its prim tree (attribute spans point into its text)
/// and its metadata.
struct Layer {
    location: Location,
    root: Prim,
    meta: Vec<(String, Val)>,
}

/// Every layer of a stage, loaded on demand.
pub(crate) struct Stage {
    /// The text of each layer, by index (the `layer` of its attributes).
    pub(crate) texts: Vec<String>,
    layers: Vec<Layer>,
    by_location: HashMap<Location, usize>,
    /// The bytes of every `.usdz` package opened.
    packages: Vec<Vec<u8>>,
    assets: UsdAssets,
    /// Arcs and sublayers that could not be followed, one line each.
    pub(crate) notes: Vec<String>,
    /// Attribute text still allowed to be copied by composition.
    budget: usize,
}

/// A layer's bytes as text: a text layer as it is, a crate file converted.
fn text_of(bytes: &[u8]) -> Result<String, ErrorKind> {
    if bytes.starts_with(b"#usda") {
        return std::str::from_utf8(bytes)
            .map(str::to_string)
            .map_err(|e| corrupt(format!("USD layer is not UTF-8 ({e})")));
    }
    if bytes.starts_with(usdc::MAGIC) {
        return usdc::layer_text(bytes);
    }
    Err(corrupt("not a USD layer (neither '#usda' text nor a PXR-USDC crate file)"))
}

/// The prim at absolute prim path `path` under `root`.
fn find<'a>(root: &'a Prim, path: &str) -> Option<&'a Prim> {
    let rest = path.strip_prefix('/')?;
    let mut p = root;
    for name in rest.split('/').filter(|n| !n.is_empty()) {
        p = p.children.iter().find(|c| c.name == name)?;
    }
    Some(p)
}

/// How much copying `prim` costs: its attributes' text and its prims.
fn weight(prim: &Prim) -> usize {
    1 + prim.attrs.iter().map(|a| 1 + a.span.len()).sum::<usize>() + prim.children.iter().map(weight).sum::<usize>()
}

/// Merges `weak` under `strong` (module notes).
pub(super) fn merge_weaker(strong: &mut Prim, weak: Prim) {
    if strong.specifier == "over" {
        strong.specifier = weak.specifier;
    }
    strong.type_name = strong.type_name.take().or(weak.type_name);
    strong.active = strong.active.or(weak.active);
    let mut attrs: Vec<_> = weak.attrs.into_iter().filter(|a| !strong.attrs.iter().any(|s| s.name == a.name)).collect();
    attrs.append(&mut strong.attrs);
    strong.attrs = attrs;
    for child in weak.children {
        match strong.children.iter_mut().find(|c| c.name == child.name) {
            Some(s) => merge_weaker(s, child),
            None => strong.children.push(child),
        }
    }
}

impl Stage {
    /// Opens the root layer `bytes` (text, crate file or package) read
    /// from `path`; returns the stage and the root layer's index.
    pub(crate) fn open(path: &Path, bytes: &[u8], assets: UsdAssets) -> Result<(Stage, usize), ErrorKind> {
        let budget = bytes.len().saturating_mul(64).saturating_add(1 << 24);
        let mut stage = Stage {
            texts: Vec::new(),
            layers: Vec::new(),
            by_location: HashMap::new(),
            packages: Vec::new(),
            assets,
            notes: Vec::new(),
            budget,
        };
        let root = if usdz::is_zip(bytes) {
            let location = stage.package(bytes.to_vec())?;
            stage.load_bytes(location, usdz::entries(bytes)?[0].1)?
        } else {
            stage.load_bytes(Location::File(path.to_path_buf()), bytes)?
        };
        Ok((stage, root))
    }

    /// Keeps a package's bytes; returns the location of its root layer.
    fn package(&mut self, bytes: Vec<u8>) -> Result<Location, ErrorKind> {
        let first = usdz::entries(&bytes)?[0].0.clone();
        let ext = first.rsplit_once('.').map(|(_, e)| e.to_ascii_lowercase());
        if !matches!(ext.as_deref(), Some("usd" | "usda" | "usdc")) {
            return Err(unsupported(format!(
                "usdz package whose first file '{}' is not a USD layer",
                first.escape_debug()
            )));
        }
        self.packages.push(bytes);
        Ok(Location::Packaged { package: self.packages.len() - 1, inner: first })
    }

    /// Parses a layer's bytes (already read) into the stage.
    fn load_bytes(&mut self, location: Location, bytes: &[u8]) -> Result<usize, ErrorKind> {
        if self.layers.len() >= MAX_LAYERS {
            return Err(corrupt(format!("more than {MAX_LAYERS} layers")));
        }
        let text = text_of(bytes)?;
        let index = self.layers.len();
        let (root, meta) = parse::layer(&text, index)?;
        self.texts.push(text);
        self.by_location.insert(location.clone(), index);
        self.layers.push(Layer { location, root, meta });
        Ok(index)
    }

    /// The layer at `location`, loading it if needed.
    fn load(&mut self, location: Location) -> Result<usize, ErrorKind> {
        if let Some(&i) = self.by_location.get(&location) {
            return Ok(i);
        }
        let bytes = match &location {
            Location::File(p) => {
                if self.assets != UsdAssets::Files {
                    return Err(unsupported("layers outside the package are not read here"));
                }
                std::fs::read(p).map_err(ErrorKind::Open)?
            }
            Location::Packaged { package, inner } => {
                let entries = usdz::entries(&self.packages[*package])?;
                let found = entries.iter().find(|(n, _)| usdz::normalize(n).as_deref() == Some(inner));
                found.ok_or_else(|| corrupt(format!("no file '{}' in the package", inner.escape_debug())))?.1.to_vec()
            }
        };
        if usdz::is_zip(&bytes) {
            let inner = self.package(bytes)?;
            let Location::Packaged { package, .. } = &inner else { unreachable!("a package location") };
            let root = self.packages[*package].clone();
            let first = usdz::entries(&root)?[0].1.to_vec();
            let index = self.load_bytes(inner, &first)?;
            self.by_location.insert(location, index);
            return Ok(index);
        }
        self.load_bytes(location, &bytes)
    }

    /// Where `asset`, named by layer `from`, is.
    fn locate(&self, from: usize, asset: &str) -> Result<Location, ErrorKind> {
        self.locate_from(&self.layers[from].location, asset)
    }

    /// Where `asset`, named by a layer at `from`, is.
    fn locate_from(&self, from: &Location, asset: &str) -> Result<Location, ErrorKind> {
        match from {
            Location::File(p) => Ok(Location::File(p.parent().unwrap_or(Path::new("")).join(asset))),
            Location::Packaged { package, inner } => {
                let dir = inner.rsplit_once('/').map_or("", |(d, _)| d);
                let inner = usdz::normalize(&format!("{dir}/{asset}"))
                    .ok_or_else(|| corrupt(format!("'{}' points outside the package", asset.escape_debug())))?;
                Ok(Location::Packaged { package: *package, inner })
            }
        }
    }

    fn spend(&mut self, prim: &Prim) -> Result<(), ErrorKind> {
        self.budget = self
            .budget
            .checked_sub(weight(prim))
            .ok_or_else(|| corrupt("composition copies far more than the layers hold"))?;
        Ok(())
    }

    fn note(&mut self, line: String) {
        if self.notes.len() < MAX_NOTES {
            self.notes.push(line);
        }
    }

    /// The file `asset` names from a layer inside a package, if some
    /// packaged layer names one that is there.
    pub(crate) fn packaged_file(&self, asset: &str) -> Option<Vec<u8>> {
        self.layers.iter().find_map(|l| {
            let Location::Packaged { package, .. } = &l.location else { return None };
            let Ok(Location::Packaged { inner, .. }) = self.locate_from(&l.location, asset) else { return None };
            let entries = usdz::entries(&self.packages[*package]).ok()?;
            entries.iter().find(|(n, _)| usdz::normalize(n).as_deref() == Some(&inner)).map(|(_, d)| d.to_vec())
        })
    }

    /// The metadata value `key` of layer `layer`.
    pub(crate) fn meta(&self, layer: usize, key: &str) -> Option<&Val> {
        self.layers[layer].meta.iter().rev().find(|m| m.0 == key).map(|m| &m.1)
    }
}

/// Composition proper.
impl Stage {
    /// Layer `layer`'s prims with their arcs followed and its sublayers
    /// merged under them.
    pub(crate) fn composed(&mut self, layer: usize, depth: usize) -> Result<Prim, ErrorKind> {
        if depth > MAX_DEPTH {
            return Err(corrupt(format!("sublayers and references nested deeper than {MAX_DEPTH} (a cycle?)")));
        }
        let mut root = self.layers[layer].root.clone();
        self.spend(&root)?;
        self.resolve(&mut root, layer, depth)?;
        let subs: Vec<String> = match self.meta(layer, "subLayers") {
            Some(Val::List(l)) => {
                l.iter().filter_map(|v| if let Val::Asset(a) = v { Some(a.clone()) } else { None }).collect()
            }
            _ => Vec::new(),
        };
        for sub in subs {
            match self.locate(layer, &sub).and_then(|l| self.load(l)) {
                Ok(s) => {
                    let weak = self.composed(s, depth + 1)?;
                    merge_weaker(&mut root, weak);
                }
                Err(e) => self.note(format!("sublayer @{}@ not read: {e}", sub.escape_debug())),
            }
        }
        Ok(root)
    }

    /// Follows the references and payloads of `prim` (of layer `layer`)
    /// and of every prim under it.
    fn resolve(&mut self, prim: &mut Prim, layer: usize, depth: usize) -> Result<(), ErrorKind> {
        for c in &mut prim.children {
            self.resolve(c, layer, depth)?;
        }
        for arc in std::mem::take(&mut prim.arcs) {
            let (asset, path) = match arc {
                Val::Arc(a, p) => (Some(a), Some(p)),
                Val::Asset(a) => (Some(a), None),
                Val::Path(p) => (None, Some(p)),
                _ => continue,
            };
            let named = format!(
                "{}{}",
                asset.as_deref().map_or(String::new(), |a| format!("@{a}@")),
                path.as_deref().map_or(String::new(), |p| format!("<{p}>"))
            );
            match self.target(layer, asset.as_deref(), path.as_deref(), depth)? {
                Ok(target) => merge_weaker(prim, target),
                Err(why) => self.note(format!(
                    "reference {} of prim '{}' not followed: {why}",
                    named.escape_debug(),
                    prim.name.escape_debug()
                )),
            }
        }
        Ok(())
    }

    /// The prim an arc of layer `layer` points to, with its own arcs
    /// followed (`Err(why)` inside when it cannot be found).
    fn target(
        &mut self,
        layer: usize,
        asset: Option<&str>,
        path: Option<&str>,
        depth: usize,
    ) -> Result<Result<Prim, String>, ErrorKind> {
        if depth >= MAX_DEPTH {
            return Err(corrupt(format!("references nested deeper than {MAX_DEPTH} (a cycle?)")));
        }
        let Some(asset) = asset else {
            // A prim of the same layer, as written there.
            let Some(raw) = path.and_then(|p| find(&self.layers[layer].root, p)).cloned() else {
                return Ok(Err("no such prim in the layer".into()));
            };
            let mut raw = raw;
            self.spend(&raw)?;
            self.resolve(&mut raw, layer, depth + 1)?;
            return Ok(Ok(raw));
        };
        let target = match self.locate(layer, asset).and_then(|l| self.load(l)) {
            Ok(t) => t,
            Err(e) => return Ok(Err(e.to_string())),
        };
        let path = match path {
            Some(p) => p.to_string(),
            None => match self.meta(target, "defaultPrim").and_then(Val::as_str) {
                Some(d) => format!("/{d}"),
                None => return Ok(Err("the layer names no defaultPrim".into())),
            },
        };
        let tree = self.composed(target, depth + 1)?;
        Ok(find(&tree, &path).cloned().ok_or_else(|| format!("no prim {} in the layer", path.escape_debug())))
    }
}
