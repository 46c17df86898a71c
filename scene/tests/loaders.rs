//! PLY / OBJ loaders on the shared real meshes and on malformed input.
use edgepoint_scene::load::{load_files, load_path, NamedBytes};
use edgepoint_scene::{NoProgress, Scene, SceneError};
mod common;
use common::data;

fn load(name: &str, bytes: &[u8]) -> Result<Scene, SceneError> {
    load_files(&[NamedBytes { name: name.into(), data: bytes.to_vec() }], &NoProgress)
}

#[test]
fn bunny_loads_and_welds() {
    let Some(p) = data("bunny/bun_zipper.ply") else { return };
    let s = load_path(&p, &NoProgress).unwrap();
    let m = &s.objects[0].mesh;
    assert_eq!(m.stats.input_triangles, 69_451);
    assert_eq!(m.stats.input_vertices, 35_947);
    // 1,113 unreferenced vertices are dropped by compaction.
    assert_eq!(m.positions.len(), 35_947 - 1_113);
    assert_eq!(m.boundary_edges(), 223);
    assert_eq!(s.objects[1].name, "floor", "staged on a floor");
    assert_eq!(s.lights.len(), 1);
    s.validate().unwrap();
}

#[test]
fn dragon_welds_to_a_closed_surface() {
    let Some(p) = data("dragon/dragon_vrip.ply") else { return };
    let t = std::time::Instant::now();
    let s = load_path(&p, &NoProgress).unwrap();
    eprintln!("dragon load + weld + adjacency: {:.0} ms", t.elapsed().as_secs_f64() * 1e3);
    let m = &s.objects[0].mesh;
    assert_eq!(m.stats.input_triangles, 871_414);
    assert_eq!(m.stats.degenerate_dropped, 108);
    assert_eq!(m.triangles.len(), 871_306);
    assert_eq!(m.boundary_edges(), 0);
    assert_eq!(m.stats.non_manifold_edges, 0);
    assert!(m.signed_volume() > 0.0, "outward winding");
}

#[test]
fn torus_is_closed_genus_one() {
    let Some(p) = data("torus/torus.obj") else { return };
    let s = load_path(&p, &NoProgress).unwrap();
    let m = &s.objects[0].mesh;
    assert_eq!(m.triangles.len(), 4_608);
    assert_eq!(m.boundary_edges(), 0);
    let euler = m.positions.len() as i64 - m.edges.len() as i64 + m.triangles.len() as i64;
    assert_eq!(euler, 0, "V - E + F = 0 for genus 1");
}

#[test]
fn cornell_official_obj_has_its_objects() {
    let Some(p) = data("cornell_box/cornell_box_official.obj") else { return };
    let s = load_path(&p, &NoProgress).unwrap();
    let names: Vec<&str> = s.objects.iter().map(|o| o.name.as_str()).collect();
    for n in ["floor", "ceiling", "back", "greenwall", "redwall", "smallbox", "largebox", "luminaire"] {
        assert!(names.contains(&n), "{n} in {names:?}");
    }
    let ceiling = &s.objects[s.object_id("ceiling").unwrap() as usize];
    assert_eq!(ceiling.mesh.triangles.len(), 4, "two quads");
    assert_eq!(s.object_id("smallbox").map(|i| s.objects[i as usize].mesh.triangles.len()), Some(12));
}

fn tetra_ply(format: &str) -> Vec<u8> {
    let pos: [[f32; 3]; 4] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let faces: [[i32; 3]; 4] = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    let mut out = format!(
        "ply\nformat {format} 1.0\ncomment test\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nelement face 4\nproperty list uchar int vertex_indices\nproperty short flags\nend_header\n"
    )
    .into_bytes();
    for p in pos {
        match format {
            "ascii" => out.extend(format!("{} {} {} 7\n", p[0], p[1], p[2]).bytes()),
            "binary_little_endian" => {
                p.iter().for_each(|v| out.extend(v.to_le_bytes()));
                out.push(7);
            }
            _ => {
                p.iter().for_each(|v| out.extend(v.to_be_bytes()));
                out.push(7);
            }
        }
    }
    for f in faces {
        match format {
            "ascii" => out.extend(format!("3 {} {} {} -2\n", f[0], f[1], f[2]).bytes()),
            "binary_little_endian" => {
                out.push(3);
                f.iter().for_each(|v| out.extend(v.to_le_bytes()));
                out.extend((-2i16).to_le_bytes());
            }
            _ => {
                out.push(3);
                f.iter().for_each(|v| out.extend(v.to_be_bytes()));
                out.extend((-2i16).to_be_bytes());
            }
        }
    }
    out
}

#[test]
fn ascii_and_binary_ply_agree() {
    let a = load("t.ply", &tetra_ply("ascii")).unwrap();
    let le = load("t.ply", &tetra_ply("binary_little_endian")).unwrap();
    let be = load("t.ply", &tetra_ply("binary_big_endian")).unwrap();
    for s in [&le, &be] {
        assert_eq!(s.objects[0].mesh.positions, a.objects[0].mesh.positions);
        assert_eq!(s.objects[0].mesh.triangles, a.objects[0].mesh.triangles);
    }
    let m = &a.objects[0].mesh;
    assert_eq!((m.triangles.len(), m.edges.len(), m.boundary_edges()), (4, 6, 0));
}

fn err(name: &str, bytes: &[u8]) -> String {
    load(name, bytes).err().unwrap_or_else(|| panic!("{name} should fail")).to_string()
}

#[test]
fn malformed_files_name_the_file_and_place() {
    let good = String::from_utf8(tetra_ply("ascii")).unwrap();
    // A non-number in vertex 1 (line 14 of the file: 12 header lines, then vertex 0).
    let bad = good.replacen("1 0 0 7", "1 0 oops 7", 1);
    let e = err("bad.ply", bad.as_bytes());
    assert!(e.contains("bad.ply") && e.contains("vertex 1") && e.contains("line 14") && e.contains("oops"), "{e}");
    // An index out of range.
    let bad = good.replacen("3 1 2 3 -2", "3 1 2 9 -2", 1);
    let e = err("idx.ply", bad.as_bytes());
    assert!(e.contains("idx.ply") && e.contains("face 3") && e.contains("vertex 9"), "{e}");
    // Truncated binary data.
    let bin = tetra_ply("binary_little_endian");
    let e = err("cut.ply", &bin[..bin.len() - 5]);
    assert!(e.contains("cut.ply") && e.contains("face 3") && e.contains("truncated"), "{e}");
    // Header problems.
    assert!(err("h.ply", b"ply\nformat ascii 1.0\nelement vertex x\nend_header\n").contains("h.ply:3"));
    assert!(err("n.ply", b"plx\n").contains("not a PLY"));
    assert!(err("f.ply", b"ply\nformat weird 1.0\nend_header\n").contains("unsupported PLY format"));
    // Non-finite coordinates.
    let bad = good.replacen("0 1 0 7", "0 inf 0 7", 1);
    assert!(err("inf.ply", bad.as_bytes()).contains("not finite"));
    // A face with two vertices.
    let bad = good.replacen("3 0 2 1 -2", "2 0 2 -2", 1);
    assert!(err("two.ply", bad.as_bytes()).contains("at least 3"));
    // OBJ: bad number, bad index, unsupported extension, empty.
    let e = err("m.obj", b"v 0 0 0\nv 1 0 0\nv 0 x 0\nf 1 2 3\n");
    assert!(e.starts_with("m.obj:3:"), "{e}");
    let e = err("m.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n");
    assert!(e.starts_with("m.obj:4:") && e.contains("vertex 4"), "{e}");
    assert!(err("m.stl", b"solid").contains("unsupported scene file type"));
    assert!(err("e.obj", b"").contains("empty"));
}

#[test]
fn obj_objects_materials_and_emitters() {
    let obj = b"mtllib m.mtl\no box\nusemtl red\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\nusemtl lamp\nv 0 2 0\nv 1 2 0\nv 1 2 1\nv 0 2 1\nf -4 -3 -2 -1\n";
    let mtl = b"newmtl red\nKd 0.8 0.1 0.1\nnewmtl lamp\nKd 0.5 0.5 0.5\nKe 4 4 4\n";
    let s = load_files(
        &[NamedBytes { name: "a/s.obj".into(), data: obj.to_vec() }, NamedBytes { name: "a/m.mtl".into(), data: mtl.to_vec() }],
        &NoProgress,
    )
    .unwrap();
    assert_eq!(s.objects.len(), 2);
    assert_eq!(s.objects[0].material.diffuse.x, 0.8);
    assert_eq!(s.objects[1].name, "box:lamp");
    assert_eq!(s.lights.len(), 1, "the emissive quad is an area light");
    assert!(s.lights[0].area() > 0.99);
    // Negative (relative) indices resolved to the last four vertices.
    assert!(s.objects[1].mesh.positions.iter().all(|p| p.y == 2.0));
}

#[test]
fn corrupted_files_never_panic() {
    let mut seeds = 0x1234_5678u64;
    let mut next = || {
        seeds = seeds.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (seeds >> 33) as usize
    };
    for fmt in ["ascii", "binary_little_endian", "binary_big_endian"] {
        let good = tetra_ply(fmt);
        for _ in 0..300 {
            let mut b = good.clone();
            match next() % 3 {
                0 => b.truncate(next() % b.len()),
                1 => {
                    let i = next() % b.len();
                    b[i] = next() as u8;
                }
                _ => {
                    let i = next() % b.len();
                    b.insert(i, next() as u8);
                }
            }
            let _ = load("x.ply", &b);
        }
    }
    let good = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".to_vec();
    for _ in 0..300 {
        let mut b = good.clone();
        let i = next() % b.len();
        b[i] = next() as u8;
        let _ = load("x.obj", &b);
    }
}

/// `grid-dragon` is built from the shared dragon, found the way the viewer finds it (the
/// test runs from the scene crate, below the worktree that has `shared/data` next to it),
/// and travels as a description plus the PLY bytes.
#[test]
fn grid_dragon_is_built_from_the_shared_dragon() {
    use edgepoint_scene::{builtin, data};
    let files = data::builtin_files("grid-dragon", None).unwrap().expect("grid-dragon has data files");
    assert_eq!(files[0].name, "grid-dragon.builtin");
    assert_eq!(files[1].name, "dragon/dragon_vrip.ply");
    let s = load_files(&files, &NoProgress).unwrap();
    s.validate().unwrap();
    assert_eq!(s.name, "grid-dragon");
    let dragon = &s.objects[s.object_id("dragon").unwrap() as usize];
    assert_eq!(dragon.mesh.triangles.len(), 871_306);
    let grid = &s.objects[s.object_id("grid").unwrap() as usize];
    let top = dragon.mesh.positions.iter().map(|p| dragon.transform.transform_point3(*p).y).fold(f32::MIN, f32::max);
    let bottom = dragon.mesh.positions.iter().map(|p| dragon.transform.transform_point3(*p).y).fold(f32::MAX, f32::min);
    let grid_bottom = grid.mesh.positions.iter().map(|p| grid.transform.transform_point3(*p).y).fold(f32::MAX, f32::min);
    assert!(bottom.abs() < 1e-6, "the dragon stands on the floor");
    assert!(grid_bottom > top + 0.05, "the grid hangs above the dragon");
    assert!(s.lights[0].center().y > grid_bottom, "the light is above the grid");
    // Without the data, the plain built-in loader explains what to do.
    assert!(builtin::load("grid-dragon").unwrap_err().contains("--data-dir"));
    // A description naming a missing data file is refused with the file named.
    let e = load_files(&files[..1], &NoProgress).unwrap_err().to_string();
    assert!(e.contains("dragon_vrip.ply"), "{e}");
}

/// Issue 12 item 1: a header count is never trusted for an allocation. The 121-byte file
/// that used to abort the process on a failed reservation of 12 PB is refused where its
/// data ends, naming the record and the count the header declared. (The counting allocator
/// of the fuzz test holds every such input to a small budget: `tests/fuzz.rs`.)
#[test]
fn header_counts_beyond_the_file_are_refused_before_anything_is_reserved() {
    let tiny = b"ply\nformat ascii 1.0\nelement vertex 1000000000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n";
    assert!(tiny.len() <= 121);
    let e = err("huge.ply", tiny);
    assert!(e.contains("huge.ply: vertex 1") && e.contains("line 9") && e.contains("1000000000000000") && e.contains("truncated"), "{e}");
    // The same count in binary: the first missing record ends it.
    let mut bin = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_vec();
    bin.extend([0u8; 24]);
    let e = err("huge.ply", &bin);
    assert!(e.contains("vertex 2") && e.contains("truncated"), "{e}");
    // The same in binary, and a face list that claims more entries than bytes follow.
    let mut bin = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uint int vertex_indices\nend_header\n".to_vec();
    for v in [[0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        v.iter().for_each(|c| bin.extend(c.to_le_bytes()));
    }
    bin.extend(4_000_000_000u32.to_le_bytes());
    bin.extend([0u8; 12]);
    let e = err("list.ply", &bin);
    assert!(e.contains("face 0") && e.contains("4000000000") && e.contains("does not fit"), "{e}");
}

/// Issue 12 item 2: an element without properties and a count of 2^64 - 1 made the reader
/// loop forever. ASCII records take a line each, so the file ends first (truncated); binary
/// records without properties take no bytes and are skipped whole.
#[test]
fn elements_without_properties_cannot_make_the_reader_spin() {
    let head = |fmt: &str| format!("ply\nformat {fmt} 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nelement nothing 18446744073709551615\nend_header\n");
    let ascii = format!("{}0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", head("ascii"));
    let e = err("spin.ply", ascii.as_bytes());
    assert!(e.contains("spin.ply: nothing 0") && e.contains("truncated"), "{e}");
    let mut bin = head("binary_little_endian").into_bytes();
    for v in [[0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        v.iter().for_each(|c| bin.extend(c.to_le_bytes()));
    }
    bin.push(3);
    [0i32, 1, 2].iter().for_each(|i| bin.extend(i.to_le_bytes()));
    let s = load("spin.ply", &bin).expect("records of no bytes are skipped");
    assert_eq!(s.objects[0].mesh.triangles.len(), 1);
    // A count beyond u64 is not a number.
    let e = err("big.ply", b"ply\nformat ascii 1.0\nelement vertex 18446744073709551616\nend_header\n");
    assert!(e.starts_with("big.ply:3:"), "{e}");
}

/// Issue 12 item 7: a second `element vertex` was read with the first one's layout (an index
/// out of bounds, answered INTERNAL). It is refused with both lines named.
#[test]
fn an_element_declared_twice_is_refused() {
    let ply = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nproperty float w\nend_header\n0 0 0\n0 0 0 0\n";
    let e = err("twice.ply", ply);
    assert!(e.starts_with("twice.ply:7:") && e.contains("declared twice") && e.contains("line 3"), "{e}");
}

/// Issue 12 item 14: data after the last declared record (a binary PLY with more faces than
/// its header declares) used to load silently without them.
#[test]
fn data_after_the_declared_records_is_an_error() {
    let mut bin = tetra_ply("binary_little_endian");
    bin.push(3);
    [0i32, 1, 2].iter().for_each(|i| bin.extend(i.to_le_bytes()));
    bin.extend((-2i16).to_le_bytes());
    let e = err("extra.ply", &bin);
    assert!(e.contains("extra.ply: byte") && e.contains("15 bytes after") && e.contains("4 `face`"), "{e}");
    let mut ascii = tetra_ply("ascii");
    ascii.extend(b"3 0 1 2 -2\n");
    let e = err("extra.ply", &ascii);
    assert!(e.starts_with("extra.ply:21:") && e.contains("after the last record"), "{e}");
    // Trailing blank lines are fine.
    let mut ascii = tetra_ply("ascii");
    ascii.extend(b"\n\n  \n");
    load("blank.ply", &ascii).unwrap();
}

/// Issue 12 items 7 and 13: coordinates that overflow rendering (3e38) are refused where
/// they are read, naming the file and the place — not later as a NaN light or a panic in a
/// built-in's builder.
#[test]
fn coordinates_beyond_the_limit_are_refused_where_they_are_read() {
    let good = String::from_utf8(tetra_ply("ascii")).unwrap();
    let bad = good.replacen("0 1 0 7", "0 3e38 0 7", 1);
    let e = err("far.ply", bad.as_bytes());
    assert!(e.contains("far.ply: vertex 2") && e.contains("line 15") && e.contains("beyond"), "{e}");
    let e = err("far.obj", b"v 0 0 0\nv 1e30 0 0\nv 0 1 0\nf 1 2 3\n");
    assert!(e.starts_with("far.obj:2:") && e.contains("beyond"), "{e}");
    let e = err("big.obj", b"v 0 0 0\nv 1e39 0 0\nv 0 1 0\nf 1 2 3\n");
    assert!(e.starts_with("big.obj:2:"), "{e}");
    // The largest accepted model still makes a valid staged scene (light and camera in range).
    let s = load("edge.obj", b"v -1e12 0 0\nv 1e12 0 0\nv 0 1e12 0\nf 1 2 3\n").unwrap();
    s.validate().unwrap();
    // grid-dragon built around a hostile dragon: refused with the data file named.
    let description = edgepoint_scene::builtin::description("grid-dragon");
    let dragon = NamedBytes { name: "dragon/dragon_vrip.ply".into(), data: bad.into_bytes() };
    let e = load_files(&[description, dragon], &NoProgress).unwrap_err().to_string();
    assert!(e.contains("dragon_vrip.ply") && e.contains("beyond"), "{e}");
}

/// Issue 12 item 4: an OBJ of many small objects welded the whole vertex list once per
/// object (quadratic: 45 s for 20,000 one-face objects). Each object's mesh is now built
/// from its own vertices only.
#[test]
fn each_obj_object_is_welded_from_its_own_vertices() {
    let (objects, vertices) = (2_000usize, 10_000usize);
    let mut text = String::new();
    for i in 0..vertices {
        text.push_str(&format!("v {} {} {}\n", i % 100, (i / 100) % 100, i % 7));
    }
    for k in 0..objects {
        let a = (k * 3) % (vertices - 2) + 1;
        text.push_str(&format!("o part{k}\nf {} {} {}\n", a, a + 1, a + 2));
    }
    let s = load("many.obj", text.as_bytes()).unwrap();
    assert_eq!(s.objects.len(), objects + 1, "every part plus the floor");
    for o in &s.objects[..objects] {
        assert_eq!(o.mesh.stats.input_vertices, 3, "{}: welded {} vertices", o.name, o.mesh.stats.input_vertices);
        assert_eq!(o.mesh.triangles.len(), 1);
    }
    // The same mesh as welding the whole list (the old way), for a part in the middle.
    let part = &s.objects[777].mesh;
    let k = 777usize;
    let a = (k * 3) % (vertices - 2);
    let p = |i: usize| glam::Vec3::new((i % 100) as f32, ((i / 100) % 100) as f32, (i % 7) as f32);
    assert_eq!(part.positions, vec![p(a), p(a + 1), p(a + 2)]);
    // Reopening an object continues its run in first-appearance order.
    let s = load("re.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\no a\nf 1 2 3\no b\nf 2 4 3\no a\nf 1 3 2\n").unwrap();
    let names: Vec<&str> = s.objects.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(names, ["a", "b", "floor"]);
    assert_eq!(s.objects[0].mesh.stats.input_triangles, 2);
}

/// Issue 12 items 6 and 14: which `mtllib` files may be read is decided in one place for the
/// viewer and the loader: files in the OBJ's directory or below; absolute paths, `..` and
/// links out of it are refused, and a refused or missing library is a warning (default
/// materials) in both.
#[test]
fn mtllib_paths_stay_inside_the_objs_directory() {
    use edgepoint_scene::load::{mtllib_names, reference_path as mtllib_path};
    let dir = std::env::temp_dir().join(format!("edgepoint-mtllib-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("scene/mat")).unwrap();
    std::fs::write(dir.join("scene/mat/ok.mtl"), b"newmtl red\nKd 0.9 0 0\n").unwrap();
    std::fs::write(dir.join("secret.mtl"), b"newmtl secret\n").unwrap();
    let scene = dir.join("scene");
    assert!(mtllib_path(&scene, "mat/ok.mtl").is_ok());
    assert!(mtllib_path(&scene, "./mat/ok.mtl").is_ok());
    for bad in ["/etc/passwd", "../secret.mtl", "mat/../../secret.mtl"] {
        let e = mtllib_path(&scene, bad).unwrap_err();
        assert!(e.contains("refused"), "{bad}: {e}");
    }
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(dir.join("secret.mtl"), scene.join("link.mtl")).unwrap();
        let e = mtllib_path(&scene, "link.mtl").unwrap_err();
        assert!(e.contains("outside"), "{e}");
    }
    assert!(mtllib_path(&scene, "gone.mtl").unwrap_err().contains("gone.mtl"));
    let obj = b"mtllib mat/ok.mtl ../secret.mtl # comment mtllib x\nmtllib gone.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl red\nf 1 2 3\n";
    assert_eq!(
        mtllib_names(obj),
        vec![(1, "mat/ok.mtl".to_string()), (1, "../secret.mtl".to_string()), (2, "gone.mtl".to_string())]
    );
    std::fs::write(scene.join("m.obj"), obj).unwrap();
    let s = load_path(&scene.join("m.obj"), &NoProgress).expect("refused and missing libraries are warnings");
    assert_eq!(s.objects[0].material.diffuse.x, 0.9, "the library it may read is used");
    let _ = std::fs::remove_dir_all(&dir);
}
