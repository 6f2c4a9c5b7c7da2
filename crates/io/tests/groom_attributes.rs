//! Attributes kept: per-point colours and widths, and a
//! USD layer's other primvars, survive a write and a read in every output
//! format that can hold them: PLY colours byte for byte with widths as
//! `thickness`, USD widths, `displayColor` and any `primvars:*` declaration
//! verbatim, cyHair colours and thickness in both; a groom of other strands
//! is refused rather than given wrong attributes.

use std::path::{Path, PathBuf};

use nst3d_io::groom::*;

fn grooms() -> PathBuf {
    let dir = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/grooms"));
    assert!(dir.is_dir(), "test data missing: {} (the shared/ data folder must sit beside the repo)", dir.display());
    dir
}

/// The bytes after `end_header\n`.
fn body(b: &[u8]) -> &[u8] {
    &b[b.windows(11).position(|w| w == b"end_header\n").expect("PLY header") + 11..]
}

/// Distinct, not round, widths for every point of `g`.
fn with_widths(mut g: Groom) -> Groom {
    for (i, s) in g.strands.iter_mut().enumerate() {
        s.widths = Some((0..s.points.len()).map(|j| 1e-3 * (1 + i + 3 * j) as f32 + 1e-9).collect());
    }
    g
}

#[test]
fn ply_keeps_uchar_colours_byte_for_byte_and_widths_exactly() {
    let dir = tempfile::tempdir().unwrap();
    // monkey_curly: 76,500 points with Blender's per-point uchar colours;
    // vertex x y z red green blue, strand nsegs, no edge element.
    let path = grooms().join("monkey_curly.ply");
    let original = std::fs::read(&path).unwrap();
    let monkey = read_ply_strands(&path).unwrap();
    assert!(monkey.strands.iter().all(|s| s.colors.is_some() && s.widths.is_none()));
    let out = dir.path().join("monkey.ply");
    write_ply_strands(&out, &monkey).unwrap();
    let written = std::fs::read(&out).unwrap();
    // The vertex and strand records are the input's bytes, colours included.
    let (n, s) = (monkey.point_count(), monkey.strand_count());
    let records = n * 15 + s * 2;
    assert_eq!(body(&written)[..records], body(&original)[..records], "vertex and strand records differ");
    assert_eq!(read_ply_strands(&out).unwrap(), monkey);

    // With widths: written as hairutil's `float thickness`, read back exactly.
    let bangs = with_widths(read_ply_strands(&grooms().join("Bangs_100_binary.ply")).unwrap());
    let out = dir.path().join("bangs.ply");
    write_ply_strands(&out, &bangs).unwrap();
    let text = String::from_utf8_lossy(&std::fs::read(&out).unwrap()[..600]).into_owned();
    assert!(text.contains("property uchar blue\nproperty float thickness\nelement strand"), "{text}");
    assert_eq!(read_ply_strands(&out).unwrap(), bangs, "colours and widths survive the PLY round trip");
    // `width` is read too (another common spelling).
    let ascii = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                 property float width\nelement strand 1\nproperty int nverts\nend_header\n0 0 0 0.5\n0 1 0 0.25\n0 2 0 0.125\n3\n";
    let p = dir.path().join("width.ply");
    std::fs::write(&p, ascii).unwrap();
    assert_eq!(read_ply_strands(&p).unwrap().strands[0].widths.as_deref(), Some(&[0.5f32, 0.25, 0.125][..]));
}

/// A layer with one curves prim: three curves (3, 2 and 4 points), constant
/// widths, uniform colours and five primvars the groom does not hold.
const LAYER: &str = r#"#usda 1.0
(
    metersPerUnit = 0.01
    upAxis = "Z"
)

def Xform "Root"
{
    def BasisCurves "Hair" (
        prepend apiSchemas = ["MaterialBindingAPI"]
    )
    {
        uniform token type = "linear"
        int[] curveVertexCounts = [3, 2, 4]
        point3f[] points = [(0, 0, 0), (0, 1, 0), (0, 2, 0), (1, 0, 0), (1, 1, 0),
                            (2, 0, 0), (2, 1, 0), (2, 2, 0), (2, 3, 0)]
        float[] widths = [0.05] (interpolation = "constant")
        color3f[] primvars:displayColor = [(0.1, 0.2, 0.3), (0.4, 0.5, 0.6), (0.7, 0.8, 0.9)] (
            interpolation = "uniform"
        )
        float[] primvars:foo = [1.5, -2, 3e-7] (interpolation = "uniform")
        color3f[] primvars:bar = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (0, 1, 1),
            (1, 0, 1), (0.25, 0.5, 0.75), (0.125, 0, 0), (0, 0, 0.0625)] (
            interpolation = "vertex"
            customData = { string note = "kept, with its metadata" }
        )
        uniform token primvars:look = "curly" (interpolation = "constant")
        float2[] primvars:uv = [(0, 0), (0.5, 1)] (interpolation = "uniform")
        int[] primvars:uv:indices = [0, 1, 0]
        float primvars:gain.timeSamples = {
            1: 0.5,
            2: 0.75,
        }
        normal3f[] normals = [(1, 0, 0)] (interpolation = "constant")
    }
}
"#;

#[test]
fn usda_keeps_widths_colours_and_every_other_primvar() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.usda");
    std::fs::write(&input, LAYER).unwrap();
    let file = read_groom_file(&input).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(read_groom(&input).unwrap(), file.groom, "read_groom and read_groom_file agree");
    let g = &file.groom;
    assert_eq!(g.strands[1].widths.as_deref(), Some(&[0.05f32; 2][..]));
    assert_eq!(g.strands[2].colors.as_deref(), Some(&[[0.7f32, 0.8, 0.9]; 4][..]));

    let pv = &file.usd_primvars;
    assert_eq!(pv.curve_points, [3, 2, 4]);
    assert_eq!((pv.up_axis.as_deref(), pv.meters_per_unit), (Some("Z"), Some(0.01)), "the layer's axis and units");
    assert!(pv.dropped.is_empty(), "{:?}", pv.dropped);
    let names: Vec<&str> = pv.primvars.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(
        names,
        ["primvars:foo", "primvars:bar", "primvars:look", "primvars:uv", "primvars:uv:indices", "primvars:gain"]
    );
    let foo = &pv.primvars[0];
    assert_eq!((foo.type_name.as_str(), foo.interpolation.as_deref()), ("float[]", Some("uniform")));
    assert_eq!(foo.declaration, r#"float[] primvars:foo = [1.5, -2, 3e-7] (interpolation = "uniform")"#);
    let bar = &pv.primvars[1];
    assert_eq!((bar.type_name.as_str(), bar.interpolation.as_deref()), ("color3f[]", Some("vertex")));
    assert!(bar.declaration.starts_with("color3f[] primvars:bar = [(1, 0, 0),") && bar.declaration.ends_with(')'));
    assert!(bar.declaration.contains("customData = { string note = \"kept, with its metadata\" }"));
    assert_eq!(pv.primvars[2].declaration, r#"uniform token primvars:look = "curly" (interpolation = "constant")"#);
    assert!(pv.primvars[5].declaration.starts_with("float primvars:gain.timeSamples = {"));

    // Moved points, the input's attributes: write, read back, all unchanged.
    let mut moved = Groom {
        strands: g
            .strands
            .iter()
            .map(|s| Strand::new(s.points.iter().map(|p| [p[0] + 0.5, p[1] * 1.25, p[2] - 1.0]).collect()))
            .collect(),
    };
    moved.copy_attributes_from(g).unwrap();
    let out = dir.path().join("out.usda");
    write_usda_curves_with(&out, &moved, pv).unwrap();
    let back = read_groom_file(&out).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(back.groom, moved, "points, widths and colours");
    assert_eq!(&back.usd_primvars, pv, "the other primvars, declaration for declaration");
    let text = std::fs::read_to_string(&out).unwrap();
    assert!(text.contains("\n    float[] primvars:foo = [1.5, -2, 3e-7] (interpolation = \"uniform\")\n"), "{text}");
    // Not a primvar: normals are not carried (the points moved).
    assert!(!text.contains("normals"), "{text}");
    // A second generation is the same file.
    let again = dir.path().join("again.usda");
    write_usda_curves_with(&again, &back.groom, &back.usd_primvars).unwrap();
    assert_eq!(std::fs::read_to_string(&again).unwrap(), text);
}

#[test]
fn primvars_of_several_curves_prims_are_merged_or_said_dropped() {
    let dir = tempfile::tempdir().unwrap();
    let prim = |name: &str, foo: &str, k: &str, extra: &str| {
        format!(
            "def BasisCurves \"{name}\"\n{{\n    uniform token type = \"linear\"\n    int[] curveVertexCounts = [2, 3]\n    \
             point3f[] points = [(0, 0, 0), (0, 1, 0), (1, 0, 0), (1, 1, 0), (1, 2, 0)]\n    \
             float[] primvars:foo = {foo} (interpolation = \"uniform\")\n    \
             float primvars:k = {k} (interpolation = \"constant\")\n    \
             string primvars:tag = \"same\"\n{extra}}}\n"
        )
    };
    let layer = format!(
        "#usda 1.0\n\n{}{}",
        prim("A", "[1, 2]", "1", "    float[] primvars:only = [4, 5] (interpolation = \"uniform\")\n"),
        prim("B", "[3,\n  4]", "2", "")
    );
    let input = dir.path().join("two.usda");
    std::fs::write(&input, layer).unwrap();
    let file = read_groom_file(&input).unwrap_or_else(|e| panic!("{e}"));
    let pv = &file.usd_primvars;
    assert_eq!(pv.curve_points, [2, 3, 2, 3]);
    let kept: Vec<(&str, &str)> = pv.primvars.iter().map(|p| (p.name.as_str(), p.declaration.as_str())).collect();
    assert_eq!(
        kept,
        [
            ("primvars:foo", r#"float[] primvars:foo = [1, 2, 3, 4] (interpolation = "uniform")"#),
            ("primvars:tag", r#"string primvars:tag = "same""#),
        ]
    );
    assert_eq!(pv.dropped.len(), 2, "{:?}", pv.dropped);
    assert!(pv.dropped[0].starts_with("primvars:k is not kept") && pv.dropped[0].contains("different values"));
    assert!(pv.dropped[1].starts_with("primvars:only is not kept") && pv.dropped[1].contains("1 of the 2"));
    let out = dir.path().join("one.usda");
    write_usda_curves_with(&out, &file.groom, pv).unwrap();
    let back = read_groom_file(&out).unwrap();
    assert_eq!(back.groom, file.groom);
    assert_eq!(back.usd_primvars.primvars, pv.primvars);
}

#[test]
fn varying_primvars_of_cubic_curves_are_said_dropped() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("cubic.usda");
    std::fs::write(
        &input,
        "#usda 1.0\n\ndef BasisCurves \"C\"\n{\n    uniform token type = \"cubic\"\n    uniform token basis = \"bezier\"\n    \
         int[] curveVertexCounts = [4]\n    point3f[] points = [(0, 0, 0), (0, 1, 0), (0, 2, 0), (0, 3, 0)]\n    \
         float[] primvars:v = [0, 1] (interpolation = \"varying\")\n    \
         float[] primvars:w = [0, 1, 2, 3] (interpolation = \"vertex\")\n}\n",
    )
    .unwrap();
    let pv = read_groom_file(&input).unwrap().usd_primvars;
    assert_eq!(pv.primvars.iter().map(|p| p.name.as_str()).collect::<Vec<_>>(), ["primvars:w"]);
    assert_eq!(pv.dropped.len(), 1);
    assert!(pv.dropped[0].starts_with("primvars:v is not kept: varying on cubic curves"), "{:?}", pv.dropped);
}

#[test]
fn other_strands_are_refused_not_given_wrong_attributes() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.usda");
    std::fs::write(&input, LAYER).unwrap();
    let file = read_groom_file(&input).unwrap();
    let mut other = file.groom.clone();
    other.strands[2].points.pop();
    other.strands[2].widths.as_mut().unwrap().pop();
    other.strands[2].colors.as_mut().unwrap().pop();
    let out = dir.path().join("out.usda");
    let e = write_usda_curves_with(&out, &other, &file.usd_primvars).unwrap_err().to_string();
    assert!(e.contains("out.usda") && e.contains("strand 2 has 3 points") && !e.contains('\n'), "{e}");
    assert!(!out.exists());
    other.strands.pop();
    let e = write_usda_curves_with(&out, &other, &file.usd_primvars).unwrap_err().to_string();
    assert!(e.contains("2 strands") && e.contains("3 curves"), "{e}");
    // Primvars the writer writes from the strands cannot be passed through.
    let mut pv = file.usd_primvars.clone();
    pv.primvars[0].name = "primvars:displayColor".into();
    assert!(write_usda_curves_with(&out, &file.groom, &pv).is_err());
    assert!(!out.exists());

    let mut bare = Groom { strands: file.groom.strands.iter().map(|s| Strand::new(s.points.clone())).collect() };
    let e = bare.copy_attributes_from(&other).unwrap_err().to_string();
    assert!(e.contains("3 strands") && e.contains("has 2"), "{e}");
    assert!(bare.strands.iter().all(|s| s.widths.is_none() && s.colors.is_none()), "a refused copy changes nothing");
    bare.copy_attributes_from(&file.groom).unwrap();
    assert_eq!(bare, file.groom);
}

/// Bangs_100.hair with thickness and colour arrays added (flags 1|2|4|16).
pub fn cyhair_with_attributes(path: &Path) -> Vec<u8> {
    let mut b = std::fs::read(path).unwrap();
    let n = u32::from_le_bytes(b[8..12].try_into().unwrap()) as usize;
    b[12..16].copy_from_slice(&(1u32 | 2 | 4 | 16).to_le_bytes());
    for i in 0..n {
        b.extend_from_slice(&(0.002 + 1e-5 * i as f32).to_le_bytes());
    }
    for i in 0..n {
        let t = i as f32 / n as f32;
        for c in [t, 1.0 - t, 0.3 + 0.1 * (i % 7) as f32 / 7.0] {
            b.extend_from_slice(&c.to_le_bytes());
        }
    }
    b
}

#[test]
fn cyhair_colours_and_thickness_reach_usda_and_ply() {
    let dir = tempfile::tempdir().unwrap();
    let hair = dir.path().join("bangs_attrs.hair");
    std::fs::write(&hair, cyhair_with_attributes(&grooms().join("Bangs_100.hair"))).unwrap();
    let g = read_groom(&hair).unwrap();
    assert!(g.strands.iter().all(|s| s.widths.is_some() && s.colors.is_some()));

    let usda = dir.path().join("bangs.usda");
    write_usda_curves(&usda, &g).unwrap();
    assert_eq!(read_usda_curves(&usda).unwrap(), g, "USD keeps both exactly");

    let ply = dir.path().join("bangs.ply");
    write_ply_strands(&ply, &g).unwrap();
    let back = read_ply_strands(&ply).unwrap();
    for (a, b) in g.strands.iter().zip(&back.strands) {
        assert_eq!((&a.points, &a.widths), (&b.points, &b.widths), "points and widths exactly");
        for (ca, cb) in a.colors.as_ref().unwrap().iter().zip(b.colors.as_ref().unwrap()) {
            for k in 0..3 {
                assert!((ca[k] - cb[k]).abs() <= 0.5 / 255.0 + 1e-7, "8-bit colour {ca:?} -> {cb:?}");
            }
        }
    }
}

/// Every prefix of the primvar layer, and random byte flips in it, read as
/// a groom file without a panic (the primvar texts are cut from the layer
/// by token positions).
#[test]
fn damaged_primvar_layers_never_panic() {
    let path = Path::new("damaged.usda");
    let layer = LAYER.as_bytes();
    let dir = tempfile::tempdir().unwrap();
    for cut in 0..layer.len() {
        if let Ok(f) = read_groom_file_bytes(path, &layer[..cut]) {
            f.groom.validate().unwrap();
        }
    }
    let mut x = 0x2545_f491_4f6c_dd1du64;
    let mut rnd = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    for _ in 0..2000 {
        let mut c = layer.to_vec();
        for _ in 0..1 + rnd() % 4 {
            let i = (rnd() as usize) % c.len();
            c[i] = b"[](){},=:\"' \n0.5-eaz#<>@\xc3\xa9"[(rnd() % 26) as usize];
        }
        if let Ok(f) = read_groom_file_bytes(path, &c) {
            f.groom.validate().unwrap();
            let _ = write_usda_curves_with(&dir.path().join("out.usda"), &f.groom, &f.usd_primvars);
        }
    }
}
