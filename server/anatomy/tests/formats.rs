//! File formats: round trips, bad files give errors that name the file and the fault, and
//! no parser panics on arbitrary bytes.

use cathlab_anatomy::io::{LengthUnit, obj, slicer, stl, swc, vtp};
use cathlab_anatomy::phantom::y_bifurcation;
use cathlab_anatomy::surface::{SurfaceSettings, lumen_surface};
use cathlab_anatomy::{AnatomyError, Lumen, TriangleMesh, VesselGraph};
use nalgebra::Point3;
use proptest::prelude::*;

fn tetrahedron_mm() -> TriangleMesh {
    let v = vec![
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(10.0, 0.0, 0.0),
        Point3::new(0.0, 10.0, 0.0),
        Point3::new(0.0, 0.0, 10.0),
    ]
    .into_iter()
    .map(|p| p * 1e-3)
    .collect();
    TriangleMesh::new(v, vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], "tet").unwrap()
}

#[test]
fn obj_and_stl_round_trip() {
    let mesh = lumen_surface(
        &y_bifurcation(3e-3, 2e-3, 10e-3, 10e-3, 0.5).unwrap(),
        &SurfaceSettings::default(),
    )
    .unwrap();
    let text = obj::to_string(&mesh, LengthUnit::Mm);
    let back = obj::parse(text.as_bytes(), LengthUnit::Mm, "y.obj").unwrap();
    assert_eq!(back.triangles, mesh.triangles);
    let worst = back
        .vertices
        .iter()
        .zip(&mesh.vertices)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(worst < 1e-12, "{worst}");
    let binary = stl::to_binary(&mesh, LengthUnit::Mm);
    let back = stl::parse(&binary, LengthUnit::Mm, "y.stl").unwrap();
    assert_eq!(back.triangles.len(), mesh.triangles.len());
    assert!(
        back.topology().is_closed_oriented_manifold(),
        "welded STL is watertight again"
    );
    assert!((back.enclosed_volume() / mesh.enclosed_volume() - 1.0).abs() < 1e-5);
}

#[test]
fn ascii_stl_and_quads_in_obj_are_read() {
    let tet = tetrahedron_mm();
    let mut ascii = String::from("solid t\n");
    for t in &tet.triangles {
        ascii += " facet normal 0 0 0\n  outer loop\n";
        for p in tet.corners(t) {
            ascii += &format!("   vertex {} {} {}\n", p.x * 1e3, p.y * 1e3, p.z * 1e3);
        }
        ascii += "  endloop\n endfacet\n";
    }
    ascii += "endsolid t\n";
    let mesh = stl::parse(ascii.as_bytes(), LengthUnit::Mm, "t.stl").unwrap();
    assert_eq!(mesh.topology().euler_characteristic, 2);
    assert!((mesh.enclosed_volume() - 1e-6 / 6.0).abs() < 1e-15);
    let quad = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1//1 2//1 3//1 4//1\n";
    assert_eq!(
        obj::parse(quad.as_bytes(), LengthUnit::Cm, "q.obj")
            .unwrap()
            .triangles
            .len(),
        2
    );
}

#[test]
fn graph_json_round_trips() {
    let graph = y_bifurcation(3e-3, 2e-3, 20e-3, 15e-3, 0.6).unwrap();
    let back = VesselGraph::from_json(&graph.to_json(), "g.json").unwrap();
    assert_eq!(back.branches.len(), 3);
    for (a, b) in graph.branches.iter().zip(&back.branches) {
        assert_eq!(a.name, b.name);
        assert!((a.length() - b.length()).abs() < 1e-15);
    }
    let err = VesselGraph::from_json("{\"nodes\": [], \"branches\": 3}", "bad.json").unwrap_err();
    assert!(err.to_string().contains("bad.json"), "{err}");
}

#[test]
fn swc_tree_becomes_branches_between_branch_points() {
    let text = "# a Y\n1 1 0 0 0 1.0 -1\n2 3 0 0 10 1.0 1\n3 3 0 0 20 1.0 2\n4 3 5 0 30 0.8 3\n5 3 -5 0 30 0.8 3\n";
    let graph = swc::parse(text.as_bytes(), LengthUnit::Mm, "y.swc").unwrap();
    assert_eq!(graph.branches.len(), 3);
    assert_eq!(graph.connected_components(), 1);
    assert!((graph.total_length() - (0.020 + 2.0 * (125f64).sqrt() * 1e-3)).abs() < 1e-12);
    let cyclic = "1 3 0 0 0 1 2\n2 3 0 0 1 1 1\n";
    assert!(
        swc::parse(cyclic.as_bytes(), LengthUnit::Mm, "c.swc")
            .unwrap_err()
            .to_string()
            .contains("c.swc")
    );
}

#[test]
fn vtp_ascii_and_binary_surfaces_and_lines() {
    let ascii = r#"<?xml version="1.0"?>
<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian">
 <PolyData><Piece NumberOfPoints="4" NumberOfPolys="4" NumberOfLines="1">
  <Points><DataArray type="Float32" NumberOfComponents="3" format="ascii">0 0 0 10 0 0 0 10 0 0 0 10</DataArray></Points>
  <PointData><DataArray type="Float32" Name="Radius" format="ascii">1 1 1 2</DataArray></PointData>
  <Polys>
   <DataArray type="Int32" Name="connectivity" format="ascii">0 2 1 0 1 3 0 3 2 1 2 3</DataArray>
   <DataArray type="Int32" Name="offsets" format="ascii">3 6 9 12</DataArray>
  </Polys>
  <Lines>
   <DataArray type="Int32" Name="connectivity" format="ascii">0 3</DataArray>
   <DataArray type="Int32" Name="offsets" format="ascii">2</DataArray>
  </Lines>
 </Piece></PolyData></VTKFile>"#;
    let data = vtp::parse(ascii.as_bytes(), LengthUnit::Mm, "t.vtp").unwrap();
    let surface = data.surface.unwrap();
    assert!(surface.topology().is_closed_oriented_manifold());
    assert_eq!(data.lines[0].radii, vec![1e-3, 2e-3]);
    // The same points as inline base64 binary with a UInt32 byte-count header.
    use base64::Engine as _;
    let mut raw = Vec::new();
    let coords: [f32; 12] = [0., 0., 0., 10., 0., 0., 0., 10., 0., 0., 0., 10.];
    raw.extend_from_slice(&(48u32).to_le_bytes());
    for c in coords {
        raw.extend_from_slice(&c.to_le_bytes());
    }
    let encoded = base64::engine::general_purpose::STANDARD.encode(&raw);
    let binary = ascii.replace(
        r#"<DataArray type="Float32" NumberOfComponents="3" format="ascii">0 0 0 10 0 0 0 10 0 0 0 10</DataArray>"#,
        &format!(r#"<DataArray type="Float32" NumberOfComponents="3" format="binary">{encoded}</DataArray>"#),
    );
    let again = vtp::parse(binary.as_bytes(), LengthUnit::Mm, "b.vtp").unwrap();
    assert_eq!(again.surface.unwrap().vertices, surface.vertices);
    let truncated = &binary[..binary.len() / 2];
    let err = vtp::parse(truncated.as_bytes(), LengthUnit::Mm, "cut.vtp").unwrap_err();
    assert!(err.to_string().starts_with("cut.vtp"), "{err}");
}

fn expect(err: AnatomyError, file: &str, words: &str) {
    let text = err.to_string();
    assert!(
        text.contains(file) && text.contains(words),
        "{text:?} should name {file} and say {words:?}"
    );
}

#[test]
fn bad_files_are_named_with_what_is_wrong() {
    expect(
        obj::parse(b"v 0 0 nan\nf 1 1 1\n", LengthUnit::Mm, "nan.obj").unwrap_err(),
        "nan.obj",
        "not finite",
    );
    expect(
        obj::parse(b"v 0 0 0\nf 1 2 3\n", LengthUnit::Mm, "idx.obj").unwrap_err(),
        "idx.obj",
        "out of range",
    );
    expect(
        obj::parse(b"# nothing\n", LengthUnit::Mm, "empty.obj").unwrap_err(),
        "empty.obj",
        "empty",
    );
    let binary = stl::to_binary(&tetrahedron_mm(), LengthUnit::Mm);
    expect(
        stl::parse(&binary[..binary.len() - 7], LengthUnit::Mm, "cut.stl").unwrap_err(),
        "cut.stl",
        "neither binary",
    );
    // An open surface (one face missing) is refused for lumen queries.
    let mut open = tetrahedron_mm();
    open.triangles.pop();
    expect(
        Lumen::new(open, "open.obj").unwrap_err(),
        "open.obj",
        "3 boundary edges",
    );
    // Millimetre coordinates declared as metres give a 400 m anatomy.
    let lcca = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../data/anatomy/arch-to-cow/centerlines/LCCA.mrk.json"
    ))
    .unwrap();
    let metres = lcca.replace("\"coordinateUnits\": \"mm\"", "\"coordinateUnits\": \"m\"");
    expect(
        slicer::parse(metres.as_bytes(), "LCCA", "lcca.mrk.json").unwrap_err(),
        "lcca.mrk.json",
        "unit",
    );
    let furlongs = lcca.replace(
        "\"coordinateUnits\": \"mm\"",
        "\"coordinateUnits\": \"furlong\"",
    );
    expect(
        slicer::parse(furlongs.as_bytes(), "LCCA", "f.mrk.json").unwrap_err(),
        "f.mrk.json",
        "furlong",
    );
    let no_radius = lcca.replace("\"name\": \"Radius\"", "\"name\": \"Diameter\"");
    expect(
        slicer::parse(no_radius.as_bytes(), "LCCA", "r.mrk.json").unwrap_err(),
        "r.mrk.json",
        "Radius",
    );
    let truncated = &lcca[..lcca.len() / 3];
    expect(
        slicer::parse(truncated.as_bytes(), "LCCA", "t.mrk.json").unwrap_err(),
        "t.mrk.json",
        "line",
    );
    expect(
        obj::parse(
            b"v 0 0 0\nv 1000 0 0\nv 0 1000 0\nf 1 2 3\n",
            LengthUnit::M,
            "big.obj",
        )
        .unwrap_err(),
        "big.obj",
        "unit",
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]
    #[test]
    fn parsers_never_panic_on_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let _ = obj::parse(&bytes, LengthUnit::Mm, "fuzz");
        let _ = stl::parse(&bytes, LengthUnit::Mm, "fuzz");
        let _ = slicer::parse(&bytes, "fuzz", "fuzz");
        let _ = swc::parse(&bytes, LengthUnit::Mm, "fuzz");
        let _ = vtp::parse(&bytes, LengthUnit::Mm, "fuzz");
        let _ = VesselGraph::from_json(&String::from_utf8_lossy(&bytes), "fuzz");
    }

    #[test]
    fn parsers_never_panic_on_mangled_valid_files(cut in 0usize..400, flip in 0usize..400, byte in any::<u8>()) {
        let obj_text = "v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
        let swc_text = "1 1 0 0 0 1.0 -1\n2 3 0 0 10 1.0 1\n3 3 0 0 20 1.0 2\n4 3 5 0 30 0.8 3\n";
        for text in [obj_text, swc_text] {
            let mut bytes = text.as_bytes().to_vec();
            let n = bytes.len();
            bytes[flip % n] = byte;
            bytes.truncate(cut % (n + 1));
            let _ = obj::parse(&bytes, LengthUnit::Mm, "m");
            let _ = swc::parse(&bytes, LengthUnit::Mm, "m");
            let _ = stl::parse(&bytes, LengthUnit::Mm, "m");
        }
    }
}

fn vtk_fixture(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/vtk")
        .join(name)
}

/// Files VTK 9 itself wrote (`tests/data/vtk/make_fixtures.py`) in every encoding it and
/// ParaView write read to the same geometry as its ASCII file.
#[test]
fn vtp_written_by_vtk_reads_the_same_in_every_encoding_including_zlib() {
    let variants = [
        "binary_zlib",
        "binary_zlib_uint64",
        "binary_raw",
        "appended_base64_zlib",
        "appended_raw_zlib",
        "appended_raw_uint64",
    ];
    let tube = vtp::load(&vtk_fixture("tube_ascii.vtp"), LengthUnit::Mm).unwrap();
    let surface = tube.surface.as_ref().unwrap();
    assert_eq!(surface.triangles.len(), 736);
    let line = vtp::load(&vtk_fixture("centerline_ascii.vtp"), LengthUnit::Mm).unwrap();
    assert_eq!(line.lines.len(), 1);
    assert_eq!(line.lines[0].radii.len(), 24);
    assert!((line.lines[0].radii[0] - 3e-3).abs() < 1e-12);
    for variant in variants {
        let other = vtp::load(&vtk_fixture(&format!("tube_{variant}.vtp")), LengthUnit::Mm)
            .unwrap_or_else(|e| panic!("{variant}: {e}"));
        let o = other.surface.as_ref().unwrap();
        assert_eq!(o.triangles, surface.triangles, "{variant}");
        for (a, b) in o.vertices.iter().zip(&surface.vertices) {
            assert!((a - b).norm() < 1e-8, "{variant}: {a} vs {b}");
        }
        let other = vtp::load(
            &vtk_fixture(&format!("centerline_{variant}.vtp")),
            LengthUnit::Mm,
        )
        .unwrap_or_else(|e| panic!("{variant}: {e}"));
        assert_eq!(other.lines.len(), 1, "{variant}");
        for (a, b) in other.lines[0].points.iter().zip(&line.lines[0].points) {
            assert!((a - b).norm() < 1e-8, "{variant}");
        }
        for (a, b) in other.lines[0].radii.iter().zip(&line.lines[0].radii) {
            assert!((a - b).abs() < 1e-12, "{variant}");
        }
    }
}

#[test]
fn damaged_compressed_vtp_is_named() {
    let good = std::fs::read(vtk_fixture("tube_binary_zlib.vtp")).unwrap();
    let text = String::from_utf8(good.clone()).unwrap();
    // An unknown compressor.
    let lz4 = text.replace("vtkZLibDataCompressor", "vtkLZ4DataCompressor");
    let err = vtp::parse(lz4.as_bytes(), LengthUnit::Mm, "lz4.vtp").unwrap_err();
    expect(err, "lz4.vtp", "vtkLZ4DataCompressor is not supported");
    // A raw appended file cut short.
    let raw = std::fs::read(vtk_fixture("tube_appended_raw_zlib.vtp")).unwrap();
    let cut = &raw[..raw.len() - 3000];
    let err = vtp::parse(cut, LengthUnit::Mm, "cut.vtp").unwrap_err();
    println!("{err}");
    assert!(err.to_string().starts_with("cut.vtp"), "{err}");
    // Flipped bits inside a zlib stream.
    let mut bad = raw.clone();
    let n = bad.len();
    for b in &mut bad[n - 2000..n - 1900] {
        *b ^= 0x5a;
    }
    let err = vtp::parse(&bad, LengthUnit::Mm, "flipped.vtp").unwrap_err();
    println!("{err}");
    assert!(err.to_string().starts_with("flipped.vtp"), "{err}");
}

#[test]
fn ply_written_by_vtk_reads_like_its_vtp_in_ascii_and_binary() {
    let vtp = vtp::load(&vtk_fixture("tube_binary_zlib.vtp"), LengthUnit::Mm).unwrap();
    let surface = vtp.surface.unwrap();
    for name in ["tube_ascii.ply", "tube_binary.ply"] {
        let ply = cathlab_anatomy::io::load_surface(&vtk_fixture(name), LengthUnit::Mm).unwrap();
        assert_eq!(ply.triangles, surface.triangles, "{name}");
        for (a, b) in ply.vertices.iter().zip(&surface.vertices) {
            assert!((a - b).norm() < 1e-8, "{name}");
        }
    }
    let bytes = std::fs::read(vtk_fixture("tube_binary.ply")).unwrap();
    let err =
        cathlab_anatomy::io::ply::parse(&bytes[..bytes.len() / 2], LengthUnit::Mm, "half.ply")
            .unwrap_err();
    expect(err, "half.ply", "PLY body ends early");
    let err = cathlab_anatomy::io::load_surface(std::path::Path::new("x.3ds"), LengthUnit::Mm)
        .unwrap_err();
    assert!(err.to_string().contains("unknown surface format"), "{err}");
}
