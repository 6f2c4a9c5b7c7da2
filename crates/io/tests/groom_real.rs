//! Groom readers and writers on the shared Bangs groom (the same 100-strand,
//! 1165-point groom stored five ways) and OpenUSD's BasisCurves example,
//! plus the robustness rule: bad bytes are one-line `Error`s, never
//! panics.

use std::path::{Path, PathBuf};

use nst3d_io::groom::*;

fn grooms() -> PathBuf {
    let dir = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/grooms"));
    assert!(dir.is_dir(), "test data missing: {} (the shared/ data folder must sit beside the repo)", dir.display());
    dir
}

fn fixtures() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures"))
}

fn bangs(name: &str) -> Groom {
    let path = grooms().join(name);
    read_groom(&path).unwrap_or_else(|e| panic!("{e}"))
}

/// Point-by-point agreement within 1e-5 relative to the groom's extent.
fn assert_same_points(a: &Groom, b: &Groom, what: &str) {
    assert_eq!(a.strand_count(), b.strand_count(), "{what}: strand count");
    let (lo, hi) = a.bbox().unwrap();
    let scale = (0..3).map(|k| (hi[k] - lo[k]).abs().max(lo[k].abs()).max(hi[k].abs())).fold(0f32, f32::max);
    for (i, (sa, sb)) in a.strands.iter().zip(&b.strands).enumerate() {
        assert_eq!(sa.points.len(), sb.points.len(), "{what}: strand {i} length");
        for (j, (p, q)) in sa.points.iter().zip(&sb.points).enumerate() {
            for k in 0..3 {
                assert!((p[k] - q[k]).abs() <= 1e-5 * scale, "{what}: strand {i} point {j}: {p:?} vs {q:?}");
            }
        }
    }
}

#[test]
fn all_bangs_formats_agree() {
    let hair = bangs("Bangs_100.hair");
    assert_eq!(hair.strand_count(), 100);
    assert_eq!(hair.point_count(), 1165);
    hair.validate().unwrap();
    for name in ["Bangs_100.data", "Bangs_100_binary.ply", "Bangs_100.abc"] {
        let g = bangs(name);
        assert_eq!((g.strand_count(), g.point_count()), (100, 1165), "{name}");
        assert_same_points(&hair, &g, name);
    }
    // The explicit readers agree with the dispatching one.
    let dir = grooms();
    assert_eq!(read_cyhair(&dir.join("Bangs_100.hair")).unwrap(), hair);
    assert_same_points(&hair, &read_hairsalon(&dir.join("Bangs_100.data")).unwrap(), "hairsalon");
    assert_same_points(&hair, &read_ply_strands(&dir.join("Bangs_100_binary.ply")).unwrap(), "ply");
    assert_same_points(&hair, &read_alembic_curves(&dir.join("Bangs_100.abc")).unwrap(), "abc");
}

#[test]
fn bangs_is_bit_identical_across_binary_formats() {
    // All were exported from one float32 groom by hairutil: no format
    // applies a transform, scale or axis change, so the floats are equal.
    let hair = bangs("Bangs_100.hair");
    for name in ["Bangs_100.data", "Bangs_100_binary.ply", "Bangs_100.abc"] {
        let g = bangs(name);
        let same = hair.strands.iter().zip(&g.strands).all(|(a, b)| a.points == b.points);
        assert!(same, "{name} differs bitwise from the .hair file");
    }
}

#[test]
fn format_detection_by_content() {
    let dir = grooms();
    for (name, f) in [
        ("Bangs_100.hair", GroomFormat::CyHair),
        ("Bangs_100.data", GroomFormat::HairSalon),
        ("Bangs_100_binary.ply", GroomFormat::Ply),
        ("Bangs_100.abc", GroomFormat::Alembic),
        ("basisCurves.usda", GroomFormat::Usda),
    ] {
        let bytes = std::fs::read(dir.join(name)).unwrap();
        assert_eq!(detect_groom_format(&dir.join(name), &bytes), Some(f), "{name}");
        // Without an extension only HairSalon relies on its exact-size check.
        assert_eq!(detect_groom_format(Path::new("noext"), &bytes), Some(f), "{name} (no extension)");
    }
}

#[test]
fn openusd_basis_curves_example() {
    let path = grooms().join("basisCurves.usda");
    let text = std::fs::read_to_string(&path).unwrap();
    // What the file says: one prim per `def BasisCurves`, curve counts in
    // each `curveVertexCounts` array.
    let prims = text.matches("def BasisCurves").count();
    let counts: Vec<usize> = text
        .lines()
        .filter(|l| l.contains("curveVertexCounts"))
        .flat_map(|l| {
            let open = l.find("= [").unwrap() + 3;
            let inside = &l[open..open + l[open..].find(']').unwrap()];
            inside.split(',').map(|x| x.trim().parse::<usize>().unwrap()).collect::<Vec<_>>()
        })
        .collect();
    assert_eq!(prims, 10);
    let g = read_usda_curves(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(g.strand_count(), counts.len());
    assert_eq!(g.point_count(), counts.iter().sum::<usize>());
    // /Linear (translate 0,9,0) / Tubes / ConstantWidth (translate 3,0,0).
    assert_eq!(g.strands[0].points[0], [3.0, 9.0, 0.0]);
    assert_eq!(g.strands[0].points[1], [4.0, 10.0, 0.0]);
    assert_eq!(g.strands[0].widths.as_deref(), Some(&[0.5f32; 7][..]));
    assert_eq!(g.strands[0].colors.as_ref().unwrap()[3], [1.0, 0.0, 0.0]);
    // /Cubic is a Scope without transform: only the prim's own translate.
    assert_eq!(g.strands[4].points[0], [3.0, 0.0, 0.0]);
    // Cubic Bezier "varying" widths [0, .8, 0] spread over 7 control points.
    let w = g.strands[5].widths.as_ref().unwrap();
    let expect = [0.0, 0.8 / 3.0, 1.6 / 3.0, 0.8, 1.6 / 3.0, 0.8 / 3.0, 0.0];
    for (a, b) in w.iter().zip(expect) {
        assert!((a - b).abs() < 1e-6, "{w:?}");
    }
}

/// The reference USD library (pxr, via tools/fixtures/io_groom_usd.py)
/// agrees with our reader on world-space points of the OpenUSD example and
/// opens the layer our writer produces with the same strands.
#[test]
fn matches_reference_usd_library() {
    let json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(fixtures().join("groom_usd_reference.json"))
            .expect("fixture missing: run tools/fixtures/io_groom_usd.py"),
    )
    .unwrap();
    let check = |g: &Groom, r: &serde_json::Value, what: &str| {
        let counts: Vec<usize> =
            r["curveVertexCounts"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap() as usize).collect();
        assert_eq!(g.strands.iter().map(|s| s.points.len()).collect::<Vec<_>>(), counts, "{what}");
        let pts: Vec<[f32; 3]> = g.strands.iter().flat_map(|s| s.points.iter().copied()).collect();
        let refp = r["points"].as_array().unwrap();
        assert_eq!(refp.len(), pts.len().min(refp.len()));
        for (i, q) in refp.iter().enumerate() {
            for k in 0..3 {
                let v = q[k].as_f64().unwrap() as f32;
                assert!((pts[i][k] - v).abs() <= 1e-5 * v.abs().max(1.0), "{what}: point {i}: {:?} vs {q}", pts[i]);
            }
        }
    };
    let example = read_usda_curves(&grooms().join("basisCurves.usda")).unwrap();
    check(&example, &json["basisCurves.usda"], "OpenUSD example");
    let ours = read_usda_curves(&fixtures().join("groom_bangs.usda")).unwrap();
    check(&ours, &json["groom_bangs.usda"], "our layer");
    assert_eq!(json["groom_bangs.usda"]["type"], "linear");
    assert_eq!(json["groom_bangs.usda"]["upAxis"], "Y");
}

/// The committed layer that pxr checked is what the writer produces now
/// (set NST3D_BLESS=1 to rewrite it after an intended writer change, then
/// rerun the pxr script).
#[test]
fn usda_writer_output_is_the_reference_checked_layer() {
    let hair = bangs("Bangs_100.hair");
    let golden = fixtures().join("groom_bangs.usda");
    if std::env::var_os("NST3D_BLESS").is_some() {
        write_usda_curves(&golden, &hair).unwrap();
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bangs.usda");
    write_usda_curves(&out, &hair).unwrap();
    assert_eq!(
        std::fs::read_to_string(&out).unwrap(),
        std::fs::read_to_string(&golden).expect("golden layer missing (NST3D_BLESS=1 writes it)")
    );
}

#[test]
fn usda_and_ply_round_trips_are_exact() {
    let dir = tempfile::tempdir().unwrap();
    let ply_groom = bangs("Bangs_100_binary.ply");
    let example = read_usda_curves(&grooms().join("basisCurves.usda")).unwrap();
    let mut synthetic = ply_groom.clone();
    for (i, s) in synthetic.strands.iter_mut().enumerate() {
        s.widths = Some((0..s.points.len()).map(|j| 0.01 * (i + j) as f32 + 1e-7).collect());
        s.points[0][0] += std::f32::consts::PI * 1e-3;
    }
    for (name, g) in [("bangs", &ply_groom), ("example", &example), ("synthetic", &synthetic)] {
        let usda = dir.path().join(format!("{name}.usda"));
        write_usda_curves(&usda, g).unwrap();
        assert_eq!(&read_usda_curves(&usda).unwrap(), g, "{name} usda round trip");
        let ply = dir.path().join(format!("{name}.ply"));
        write_ply_strands(&ply, g).unwrap();
        let back = read_ply_strands(&ply).unwrap();
        // PLY keeps points and widths (`thickness`) exactly, and colours
        // that are whole 8-bit values, as all of these are; a groom without
        // colours comes back white.
        let mut expect = g.clone();
        for s in &mut expect.strands {
            s.colors.get_or_insert_with(|| vec![[1.0; 3]; s.points.len()]);
        }
        assert_eq!(back, expect, "{name} ply round trip");
    }
    // Our PLY has the shared file's header, byte for byte, but its comment.
    let ply = dir.path().join("bangs.ply");
    let ours = std::fs::read(&ply).unwrap();
    let theirs = std::fs::read(grooms().join("Bangs_100_binary.ply")).unwrap();
    let header = |b: &[u8]| {
        let s = String::from_utf8_lossy(&b[..b.windows(10).position(|w| w == b"end_header").unwrap()]).into_owned();
        s.lines().filter(|l| !l.starts_with("comment")).map(str::to_string).collect::<Vec<_>>()
    };
    assert_eq!(header(&ours), header(&theirs));
    assert_eq!(read_ply_strands(&ply).unwrap(), ply_groom, "colours survive too");
    // Same layout, same values: the body is byte-identical to hairutil's.
    let body = |b: &[u8]| b[b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11..].to_vec();
    assert_eq!(body(&ours), body(&theirs));
}

#[test]
fn ascii_ply_and_other_strand_delimiters() {
    let dir = tempfile::tempdir().unwrap();
    let expect = Groom {
        strands: vec![
            Strand::new(vec![[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 2.0, 0.5]]),
            Strand::new(vec![[1.0, 0.0, 0.0], [1.0, 1.5, 0.0]]),
        ],
    };
    let cases = [
        "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\n\
         element strand 2\nproperty ushort nsegs\nend_header\n0 0 0\n0 1 0\n0 2 0.5\n1 0 0\n1 1.5 0\n2\n1\n",
        "ply\nformat ascii 1.0\nelement vertex 5\nproperty double x\nproperty double y\nproperty double z\n\
         property int strand_id\nend_header\n0 0 0 7\n0 1 0 7\n0 2 0.5 7\n1 0 0 3\n1 1.5 0 3\n",
        "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\n\
         element edge 3\nproperty int vertex1\nproperty int vertex2\nend_header\n0 0 0\n0 1 0\n0 2 0.5\n1 0 0\n1 1.5 0\n0 1\n1 2\n3 4\n",
    ];
    for (i, text) in cases.iter().enumerate() {
        let p = dir.path().join(format!("case{i}.ply"));
        std::fs::write(&p, text).unwrap();
        assert_eq!(read_ply_strands(&p).unwrap_or_else(|e| panic!("case {i}: {e}")), expect, "case {i}");
    }
}

#[test]
fn validate_names_the_strand() {
    let mut g = Groom { strands: vec![Strand::new(vec![[0.0; 3], [1.0; 3]]); 3] };
    g.validate().unwrap();
    g.strands[2].points[1][1] = f32::NAN;
    let e = g.validate().unwrap_err().to_string();
    assert!(e.contains("strand 2") && e.contains("not finite"), "{e}");
    g.strands[1].points.truncate(1);
    assert!(g.validate().unwrap_err().to_string().contains("strand 1"));
    assert!(matches!(Groom::default().validate(), Err(GroomError::NoStrands)));
    assert_eq!(g.bbox().map(|b| b.0), Some([0.0; 3]));
    // Writers refuse invalid grooms instead of writing garbage.
    let dir = tempfile::tempdir().unwrap();
    assert!(write_usda_curves(&dir.path().join("x.usda"), &g).is_err());
    assert!(!dir.path().join("x.usda").exists());
}

#[test]
fn missing_file_is_a_named_error() {
    let e = read_groom(Path::new("/nonexistent/dir/x.hair")).unwrap_err().to_string();
    assert!(e.contains("/nonexistent/dir/x.hair") && e.contains("cannot read"), "{e}");
    let e = read_groom_bytes(Path::new("thing.xyz"), b"hello").unwrap_err().to_string();
    assert!(e.contains("thing.xyz"), "{e}");
}

/// Every prefix of every shared file fails cleanly with a one-line message
/// naming the file.
#[test]
fn truncated_files_fail_cleanly() {
    for name in ["Bangs_100.hair", "Bangs_100.data", "Bangs_100_binary.ply", "Bangs_100.abc", "basisCurves.usda"] {
        let path = grooms().join(name);
        let bytes = std::fs::read(&path).unwrap();
        let step = (bytes.len() / 300).max(1);
        let mut cuts: Vec<usize> = (0..bytes.len()).step_by(step).collect();
        cuts.extend(0..200.min(bytes.len()));
        cuts.extend(bytes.len() - 64..bytes.len());
        for cut in cuts {
            let prefix = &bytes[..cut];
            match read_groom_bytes(&path, prefix) {
                Ok(g) => {
                    // A text prefix may end between prims and still be valid
                    // USD, giving the first prims' curves; anything else
                    // must fail.
                    assert!(name.ends_with(".usda"), "{name}: cut {cut} parsed");
                    let full = read_groom(&path).unwrap();
                    assert_eq!(g.strands[..], full.strands[..g.strand_count()], "cut {cut}");
                }
                Err(e) => {
                    let msg = e.to_string();
                    assert!(msg.contains(name) && !msg.contains('\n'), "cut {cut}: {msg}");
                }
            }
        }
    }
}

/// Random bytes, random bytes behind a real header, and byte flips inside
/// real files never panic.
#[test]
fn random_and_corrupted_bytes_never_panic() {
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    let mut rnd = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let names = ["Bangs_100.hair", "Bangs_100.data", "Bangs_100_binary.ply", "Bangs_100.abc", "basisCurves.usda"];
    let files: Vec<(PathBuf, Vec<u8>)> =
        names.iter().map(|n| (grooms().join(n), std::fs::read(grooms().join(n)).unwrap())).collect();
    for trial in 0..3000 {
        let (path, real) = &files[trial % files.len()];
        let len = (rnd() % 2048) as usize;
        let mut b: Vec<u8> = (0..len).map(|_| rnd() as u8).collect();
        let keep = (rnd() % 400) as usize;
        if trial % 2 == 0 && b.len() > keep {
            b[..keep].copy_from_slice(&real[..keep]);
        }
        let _ = read_groom_bytes(path, &b);
        let mut c = real.clone();
        for _ in 0..1 + trial % 5 {
            let i = (rnd() as usize) % c.len();
            c[i] = rnd() as u8;
        }
        if let Ok(g) = read_groom_bytes(path, &c) {
            g.validate().unwrap();
        }
    }
}
