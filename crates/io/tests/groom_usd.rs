//! Binary USD grooms against the reference implementation: files PyPI's
//! usd-core wrote (a crate file, a package, a stage that sublayers one and
//! one that references it, each as usd-core read them: `facts.json`, from
//! `tools/usd_groom.py fixtures`) read with the same curves, world points,
//! widths, colours, primvars, `upAxis` and `metersPerUnit`; our crate
//! files and packages read back exactly; broken ones fail in one line.
//!
//! The files are the committed ones under `tests/fixtures/usd`, or those
//! in `$NST3D_USD_REFERENCE` (tools/test_usd.sh makes them there with the
//! usd-core it installs, so CI checks the library as it is today).

use std::path::{Path, PathBuf};

use nst3d_io::groom::{
    detect_groom_format, read_groom, read_groom_bytes, read_groom_file, read_groom_file_bytes,
    read_usd_curves_file_bytes, write_usda_curves_with, write_usdc_curves_with, write_usdz_curves_with, GroomFile,
    GroomFormat, UsdAssets,
};
use serde_json::Value;

fn reference() -> PathBuf {
    let dir = match std::env::var_os("NST3D_USD_REFERENCE") {
        Some(d) => PathBuf::from(d),
        None => PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/usd")),
    };
    assert!(
        dir.join("facts.json").is_file(),
        "{}: no facts.json (tools/usd_groom.py fixtures writes it)",
        dir.display()
    );
    dir
}

fn facts() -> Value {
    serde_json::from_str(&std::fs::read_to_string(reference().join("facts.json")).unwrap()).unwrap()
}

/// Every number (and quoted string) in a value, depth first.
fn flatten(v: &Value, out: &mut Vec<String>) {
    match v {
        Value::Array(a) => a.iter().for_each(|x| flatten(x, out)),
        Value::Number(n) => out.push(format!("{}", n.as_f64().unwrap() as f32)),
        Value::String(s) => out.push(s.clone()),
        Value::Bool(b) => out.push(format!("{}", *b as i32)),
        Value::Null | Value::Object(_) => {}
    }
}

/// The numbers and strings of the values a primvar's declaration
/// assigns (metadata and type names left out), as `flatten` spells them.
fn declared(decl: &str) -> Vec<String> {
    let mut out = Vec::new();
    for line in decl.lines() {
        // Statements have a type and a name before ` = `; metadata lines
        // (`interpolation = ...`) one word.
        let Some((_, value)) = line.split_once(" = ").filter(|(h, _)| h.trim().contains(' ')) else { continue };
        let mut rest = value.strip_suffix(" (").unwrap_or(value);
        while !rest.is_empty() {
            if let Some(q) = rest.strip_prefix('"') {
                let (mut text, mut chars) = (String::new(), q.char_indices());
                while let Some((i, c)) = chars.next() {
                    match c {
                        '\\' => text.extend(chars.next().map(|(_, e)| e)),
                        '"' => {
                            rest = &q[i + 1..];
                            break;
                        }
                        c => text.push(c),
                    }
                }
                out.push(text);
                continue;
            }
            if let Some(a) = rest.strip_prefix('@') {
                let end = a.find('@').unwrap();
                out.push(a[..end].to_string());
                rest = &a[end + 1..];
                continue;
            }
            let n = rest.find(|c: char| !(c.is_ascii_digit() || "eE.+-".contains(c))).unwrap_or(rest.len());
            if n > 0 {
                out.push(format!("{}", rest[..n].parse::<f64>().unwrap() as f32));
                rest = &rest[n..];
            } else {
                rest = &rest[rest.chars().next().unwrap().len_utf8()..];
            }
        }
    }
    out
}

/// Our reading of `name` agrees with usd-core's facts about it.
fn check_file(name: &str, f: &Value, ours: &GroomFile) {
    let curves = f["curves"].as_array().unwrap();
    let counts: Vec<usize> = curves
        .iter()
        .flat_map(|c| c["curveVertexCounts"].as_array().unwrap().iter().map(|n| n.as_u64().unwrap() as usize))
        .collect();
    let g = &ours.groom;
    assert_eq!(g.strands.iter().map(|s| s.points.len()).collect::<Vec<_>>(), counts, "{name}: topology");
    let pts: Vec<[f32; 3]> = g.strands.iter().flat_map(|s| s.points.iter().copied()).collect();
    let theirs: Vec<&Value> = curves.iter().flat_map(|c| c["points"].as_array().unwrap()).collect();
    for (i, (p, q)) in pts.iter().zip(&theirs).enumerate() {
        for k in 0..3 {
            let v = q[k].as_f64().unwrap() as f32;
            assert!((p[k] - v).abs() <= 1e-6 * v.abs().max(1.0), "{name}: point {i}: {p:?} vs {q}");
        }
    }
    let widths: Vec<f32> = g.strands.iter().flat_map(|s| s.widths.clone().unwrap()).collect();
    let want: Vec<f32> = curves[0]["widths"].as_array().unwrap().iter().map(|w| w.as_f64().unwrap() as f32).collect();
    assert_eq!(widths, want, "{name}: widths");
    let p = &ours.usd_primvars;
    assert_eq!(p.up_axis.as_deref().unwrap_or("Y"), f["upAxis"], "{name}: upAxis");
    // usd-core answers its fallback (centimetres) when none is authored.
    assert_eq!(p.meters_per_unit.unwrap_or(0.01), f["metersPerUnit"].as_f64().unwrap(), "{name}: metersPerUnit");
    assert!(p.dropped.is_empty(), "{name}: {:?}", p.dropped);
    let theirs = curves[0]["primvars"].as_object().unwrap();
    // usd-core lists an indexed primvar once; its indices are a primvar
    // of their own here.
    let mut names: Vec<String> = theirs.keys().filter(|k| *k != "primvars:displayColor").cloned().collect();
    let mut kept: Vec<String> =
        p.primvars.iter().map(|x| x.name.clone()).filter(|n| !n.ends_with(":indices")).collect();
    names.sort();
    kept.sort();
    assert_eq!(kept, names, "{name}: primvars");
    for pv in &p.primvars {
        let Some(t) = theirs.get(&pv.name) else { continue };
        assert_eq!(pv.type_name, t["type"], "{name}: {} type", pv.name);
        assert_eq!(pv.interpolation.as_deref().unwrap_or("constant"), t["interpolation"], "{name}: {}", pv.name);
        if t.get("value").is_none() {
            continue;
        }
        let mut want = Vec::new();
        flatten(&t["value"], &mut want);
        flatten(&t["samples"], &mut want);
        assert_eq!(declared(&pv.declaration), want, "{name}: {} values\n{}", pv.name, pv.declaration);
        if let Some(ix) = t["indices"].as_array() {
            let decl = &p.primvars.iter().find(|x| x.name == format!("{}:indices", pv.name)).unwrap().declaration;
            let mut want = Vec::new();
            flatten(&Value::Array(ix.clone()), &mut want);
            assert_eq!(declared(decl), want, "{name}: {} indices", pv.name);
        }
    }
    if let Some(c) = theirs.get("primvars:displayColor").and_then(|c| c.get("value")) {
        let colors: Vec<[f32; 3]> = g.strands.iter().flat_map(|s| s.colors.clone().unwrap()).collect();
        let want: Vec<[f32; 3]> =
            c.as_array().unwrap().iter().map(|v| [0, 1, 2].map(|k| v[k].as_f64().unwrap() as f32)).collect();
        assert_eq!(colors, want, "{name}: displayColor");
    }
}

/// A style map read from a primvar (`UsdPrimvars::strand_values`) is, for
/// every number primvar usd-core wrote, the value usd-core reads for each
/// curve: its own where `uniform`, its root point's where `vertex`, the
/// one value (or the earliest sample) where `constant`, indices followed;
/// every other primvar is refused.
#[test]
fn map_primvars_are_what_usd_core_reads_per_curve() {
    let all = facts();
    for (name, f) in all.as_object().unwrap() {
        let ours = read_groom_file(&reference().join(name)).unwrap_or_else(|e| panic!("{e}"));
        let counts: Vec<usize> = ours.groom.strands.iter().map(|s| s.points.len()).collect();
        for (pv, t) in f["curves"][0]["primvars"].as_object().unwrap() {
            let got = ours.usd_primvars.strand_values(pv);
            let scalar = ["float", "double", "half", "int", "uint", "int64", "uint64", "uchar", "bool"]
                .contains(&t["type"].as_str().unwrap().trim_end_matches("[]"));
            if !scalar || t["elementSize"].as_u64() != Some(1) || pv == "primvars:displayColor" {
                assert!(got.is_err(), "{name}: {pv} ({}) read as a map", t["type"]);
                continue;
            }
            if t.get("value").is_none() {
                // usd-core's facts hold the values once, in groom.usdc.
                assert!(got.is_ok(), "{name}: {pv}: {got:?}");
                continue;
            }
            let number = |v: &Value| v.as_f64().or_else(|| v.as_bool().map(f64::from)).unwrap() as f32;
            let value = match &t["value"] {
                Value::Null => t["samples"][0][1].clone(),
                v => v.clone(),
            };
            let mut all: Vec<f32> = match &value {
                Value::Array(a) => a.iter().map(number).collect(),
                v => vec![number(v)],
            };
            if let Some(ix) = t["indices"].as_array() {
                all = ix.iter().map(|i| all[i.as_u64().unwrap() as usize]).collect();
            }
            let starts = counts.iter().scan(0, |at, n| Some(std::mem::replace(at, *at + n)));
            let want: Vec<f32> = match t["interpolation"].as_str().unwrap() {
                "constant" => vec![all[0]; counts.len()],
                "uniform" => all,
                _ => starts.map(|s| all[s]).collect(),
            };
            assert_eq!(got.unwrap_or_else(|e| panic!("{name}: {e}")), want, "{name}: {pv}");
        }
    }
}

/// Every file usd-core wrote reads as usd-core reads it: crate file,
/// package, a sublayer with an over adding a primvar, a reference with a
/// stronger translate, and a package holding a layer and the layer it
/// references.
#[test]
fn reads_what_usd_core_reads() {
    let all = facts();
    let dir = reference();
    for (name, f) in all.as_object().unwrap() {
        let ours = read_groom_file(&dir.join(name)).unwrap_or_else(|e| panic!("{e}"));
        check_file(name, f, &ours);
        assert_eq!(read_groom(&dir.join(name)).unwrap(), ours.groom, "{name}: read_groom agrees");
    }
    assert_eq!(all.as_object().unwrap().len(), 5, "groom.usdc, groom.usdz, shot.usda, asset.usdc, asset.usdz");
}

/// A package is read whole from its bytes; a layer that points outside it
/// is not followed unless files may be read.
#[test]
fn packages_need_no_files_and_layers_outside_need_permission() {
    let dir = reference();
    let bytes = std::fs::read(dir.join("asset.usdz")).unwrap();
    let from_bytes =
        read_usd_curves_file_bytes(Path::new("nowhere/asset.usdz"), &bytes, UsdAssets::PackageOnly).unwrap();
    assert_eq!(from_bytes, read_groom_file(&dir.join("asset.usdz")).unwrap());
    let shot = std::fs::read(dir.join("shot.usda")).unwrap();
    let err =
        read_usd_curves_file_bytes(&dir.join("shot.usda"), &shot, UsdAssets::PackageOnly).unwrap_err().to_string();
    assert!(err.contains("sublayer") && err.lines().count() == 1, "{err}");
}

/// Our crate files and packages read back as what was written: the
/// strands bit for bit, every primvar as it was, the axis and units.
#[test]
fn our_crate_files_and_packages_read_back_exactly() {
    let input = read_groom_file(&reference().join("groom.usdc")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let mut moved = input.groom.clone();
    for (i, s) in moved.strands.iter_mut().enumerate() {
        s.points.iter_mut().for_each(|p| p[1] += 1e-3 * i as f32 + std::f32::consts::PI * 1e-7);
    }
    for ext in ["usdc", "usdz", "usda"] {
        let out = tmp.path().join(format!("styled.{ext}"));
        match ext {
            "usdc" => write_usdc_curves_with(&out, &moved, &input.usd_primvars).unwrap(),
            "usdz" => write_usdz_curves_with(&out, &moved, &input.usd_primvars).unwrap(),
            _ => write_usda_curves_with(&out, &moved, &input.usd_primvars).unwrap(),
        }
        let back = read_groom_file(&out).unwrap();
        assert_eq!(back.groom, moved, "{ext}: strands");
        assert_eq!(back.usd_primvars.up_axis, input.usd_primvars.up_axis, "{ext}");
        assert_eq!(back.usd_primvars.meters_per_unit, input.usd_primvars.meters_per_unit, "{ext}");
        if ext != "usda" {
            assert_eq!(back.usd_primvars.primvars, input.usd_primvars.primvars, "{ext}: primvars");
        }
        let names: Vec<_> = back.usd_primvars.primvars.iter().map(|p| &p.name).collect();
        assert_eq!(names, input.usd_primvars.primvars.iter().map(|p| &p.name).collect::<Vec<_>>(), "{ext}");
    }
    // A package's texture, named by an asset primvar, goes into the package
    // written from it.
    let packaged = read_groom_file(&reference().join("groom.usdz")).unwrap();
    assert_eq!(packaged.usd_primvars.files.len(), 1, "the texture primvars:map names");
    let out = tmp.path().join("again.usdz");
    write_usdz_curves_with(&out, &packaged.groom, &packaged.usd_primvars).unwrap();
    assert_eq!(read_groom_file(&out).unwrap(), packaged);
    // A groom without USD primvars: the same.
    let bangs =
        read_groom(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/grooms/Bangs_100.hair")))
            .expect("../shared/data must sit beside the repository");
    let out = tmp.path().join("bangs.usdc");
    write_usdc_curves_with(&out, &bangs, &Default::default()).unwrap();
    assert_eq!(read_groom(&out).unwrap(), bangs);
}

/// Binary USD is recognised by content (a crate file named `.usd`, a
/// package by its first file), and a broken one, cut or flipped
/// anywhere, fails in one line naming the file, never a panic.
#[test]
fn broken_binary_usd_fails_in_one_line() {
    let dir = reference();
    for name in ["groom.usdc", "groom.usdz"] {
        let bytes = std::fs::read(dir.join(name)).unwrap();
        let want = if name.ends_with('c') { GroomFormat::Usdc } else { GroomFormat::Usdz };
        assert_eq!(detect_groom_format(Path::new("g.usd"), &bytes), Some(want), "{name}");
        assert_eq!(detect_groom_format(Path::new("g.bin"), &bytes), Some(want), "{name}");
        let path = Path::new("broken").join(name);
        let check = |b: &[u8], what: &str| {
            if let Err(e) = read_groom_file_bytes(&path, b) {
                let e = e.to_string();
                assert!(e.lines().count() == 1 && e.contains(name), "{name} {what}: {e}");
            }
            let _ = read_groom_bytes(&path, b);
        };
        // A package cut after its layer's data (in its directory, which
        // readers do not need) still holds the layer.
        let half = |at: usize| u16::from_le_bytes([bytes[at], bytes[at + 1]]) as usize;
        let size = u32::from_le_bytes(bytes[18..22].try_into().unwrap()) as usize;
        let whole = if name.ends_with('z') { 30 + half(26) + half(28) + size } else { bytes.len() };
        for cut in (0..bytes.len()).step_by(7) {
            assert!(cut >= whole || read_groom_file_bytes(&path, &bytes[..cut]).is_err(), "{name} cut at {cut}");
            check(&bytes[..cut], "cut");
        }
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..1000 {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let mut b = bytes.clone();
            let at = (state >> 33) as usize % b.len();
            b[at] ^= 1 << ((state >> 20) % 8);
            check(&b, &format!("flipped at {at}"));
        }
    }
    let mut header_only = b"PXR-USDC".to_vec();
    header_only.extend_from_slice(&[0, 8, 0, 0, 0, 0, 0, 0]);
    header_only.resize(88, 0);
    let e = read_groom_file_bytes(Path::new("g.usd"), &header_only).unwrap_err().to_string();
    assert!(e.lines().count() == 1 && e.contains("g.usd"), "{e}");
}

/// Every value type a primvar can have comes back from a crate file as
/// it was written in text: scalars, vectors, quaternions, matrices
/// (inlined or not), text types, arrays (empty too), time samples with a
/// blocked sample, and the `uniform`, `custom`, `elementSize` and `doc`
/// that go with them.
#[test]
fn every_value_type_survives_a_crate_file() {
    let primvars = [
        "bool primvars:a = 1",
        "uchar primvars:b = 200",
        "int primvars:c = -7",
        "uint primvars:d = 4000000000",
        "int64 primvars:e = -9000000000000",
        "uint64 primvars:f = 18000000000000000000",
        "half primvars:g = 0.33325195",
        "float primvars:h = 3.4028235e38",
        "double primvars:i = 0.1",
        "timecode primvars:j = 24",
        "string primvars:k = \"a \\\"quoted\\\"\\nline\"",
        "token primvars:l = \"front\"",
        "asset primvars:m = @textures/hair.png@",
        "int2 primvars:n = (1, -2)",
        "half3 primvars:o = (0.5, 1000, -2)",
        "float4 primvars:p = (0.1, 0.2, 0.3, 0.4)",
        "double2 primvars:q = (1e-300, 2)",
        "point3f primvars:r = (1, 2, 3)",
        "normal3d primvars:s = (0, 0.6, 0.8)",
        "color4h primvars:t = (1, 0.5, 0.25, 1)",
        "quatf primvars:u = (1, 0, 0, 0)",
        "quatd primvars:v = (0.5, 0.5, 0.5, 0.5)",
        "quath primvars:w = (0, 1, 0, 0)",
        "matrix2d primvars:x = ((2, 0), (0, 3))",
        "matrix3d primvars:y = ((1, 0.5, 0), (0, 1, 0), (0, 0, 1))",
        "matrix4d primvars:z = ((1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (5, 6, 7, 1))",
        "bool[] primvars:aa = [1, 0]",
        "int[] primvars:ab = []",
        "uint64[] primvars:ac = [1, 18000000000000000000]",
        "half[] primvars:ad = [0.5, -1.5]",
        "double[] primvars:ae = [0.1, 0.2]",
        "string[] primvars:af = [\"x\", \"\"]",
        "token[] primvars:ag = [\"a\", \"b\"]",
        "asset[] primvars:ah = [@a.png@, @b.png@]",
        "texCoord2f[] primvars:ai = [(0, 1), (0.5, 0.25)]",
        "quatf[] primvars:aj = [(1, 0, 0, 0), (0, 0, 0, 1)]",
        "matrix4d[] primvars:ak = [((1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1))]",
        "custom uniform float[] primvars:al = [1, 2] (\n        interpolation = \"uniform\"\n    )",
        "float[] primvars:am = [1, 2, 3, 4] (\n        interpolation = \"uniform\"\n        elementSize = 2\n        doc = \"two per curve\"\n    )",
        "float primvars:an.timeSamples = { 1: 0.25, 2: None, 3.5: 0.75 }",
    ];
    let layer = format!(
        "#usda 1.0\n(\n    upAxis = \"Z\"\n)\n\ndef BasisCurves \"C\"\n{{\n    int[] curveVertexCounts = [2, 2]\n    \
         point3f[] points = [(0, 0, 0), (0, 1, 0), (1, 0, 0), (1, 1, 0)]\n    {}\n}}\n",
        primvars.join("\n    ")
    );
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("in.usda"), &layer).unwrap();
    let input = read_groom_file(&tmp.path().join("in.usda")).unwrap();
    assert_eq!(input.usd_primvars.primvars.len(), primvars.len(), "{:?}", input.usd_primvars.dropped);
    assert!(nst3d_io::groom::usdc_unwritable(&input.usd_primvars).is_empty());
    let out = tmp.path().join("out.usdc");
    write_usdc_curves_with(&out, &input.groom, &input.usd_primvars).unwrap();
    let back = read_groom_file(&out).unwrap();
    let flat = |s: &str| s.split_whitespace().collect::<Vec<_>>().join(" ");
    for (a, b) in input.usd_primvars.primvars.iter().zip(&back.usd_primvars.primvars) {
        assert_eq!((&a.name, &a.type_name, &a.interpolation), (&b.name, &b.type_name, &b.interpolation));
        assert_eq!(flat(&a.declaration), flat(&b.declaration), "{}", a.name);
    }
    assert_eq!(back.usd_primvars.primvars.len(), primvars.len());
}

/// A reference that cannot be followed (a missing asset beside the
/// groom) is a note and the curves are read; one that loops on itself
/// fails in one line.
#[test]
fn arcs_that_cannot_be_followed_are_notes_and_cycles_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let hair = "def BasisCurves \"Hair\"\n{\n    int[] curveVertexCounts = [2]\n    \
                point3f[] points = [(0, 0, 0), (0, 1, 0)]\n}\n";
    let shot = tmp.path().join("shot.usda");
    std::fs::write(
        &shot,
        format!("#usda 1.0\n\ndef Xform \"Head\" (\n    references = @head.usdc@</Head>\n)\n{{\n}}\n{hair}"),
    )
    .unwrap();
    let read = read_groom_file(&shot).unwrap();
    assert_eq!(read.groom.point_count(), 2);
    assert_eq!(read.usd_primvars.dropped.len(), 1, "{:?}", read.usd_primvars.dropped);
    assert!(read.usd_primvars.dropped[0].contains("@head.usdc@") && read.usd_primvars.dropped[0].contains("Head"));
    let looped = tmp.path().join("loop.usda");
    std::fs::write(
        &looped,
        format!("#usda 1.0\n\ndef Xform \"X\" (\n    references = @loop.usda@</X>\n)\n{{\n}}\n{hair}"),
    )
    .unwrap();
    let e = read_groom_file(&looped).unwrap_err().to_string();
    assert!(e.lines().count() == 1 && e.contains("cycle"), "{e}");
}
