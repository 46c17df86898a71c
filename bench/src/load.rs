//! `edgepoint-bench load`: how long a scene takes to become renderable — parse + weld +
//! edge adjacency (scene crate) and the two-level BVH build (worker) — measured in-process.
use anyhow::{Context, Result};
use edgepoint_scene::load::{load_files, NamedBytes};
use edgepoint_scene::NoProgress;
use edgepoint_server::reference::LogProgress;
use serde_json::json;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct LoadArgs {
    /// A .ply / .obj file (e.g. ../shared/data/dragon/dragon_vrip.ply); the same as --scene PATH.
    #[arg(long, conflicts_with = "scene")]
    pub mesh: Option<std::path::PathBuf>,
    /// A built-in scene name or a scene file (.ply, .obj, Mitsuba .xml, .gltf, .glb; also .gz) [default: cornell].
    #[arg(long)]
    pub scene: Option<String>,
    /// Repeat the measurement this many times and report the median.
    #[arg(long, default_value_t = 3)]
    pub repeat: u32,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Compare the scene formats on one mesh: the --mesh PLY is written in memory as OBJ,
    /// gzipped OBJ and PLY, glTF (.gltf + .bin), GLB and a Mitsuba XML naming the PLY, and
    /// each is loaded (parse + weld + adjacency) in this process; times are medians of
    /// --repeat, ratios against the PLY loader on the same mesh.
    #[arg(long, requires = "mesh")]
    pub formats: bool,
}

pub fn run(a: LoadArgs) -> Result<()> {
    if a.formats {
        return run_formats(&a);
    }
    let what = match (&a.mesh, &a.scene) {
        (Some(p), _) => p.display().to_string(),
        (None, Some(s)) => s.clone(),
        (None, None) => "cornell".to_string(),
    };
    // Read the files once, outside the timing: the workers parse scenes from bytes too.
    let source = edgepoint_viewer::client::scene_source_from_arg(&what)?;
    let (mut load_ms, mut bvh_ms) = (Vec::new(), Vec::new());
    let mut summary = json!({});
    for i in 0..a.repeat.max(1) {
        let progress = LogProgress::new(&format!("load {what}"));
        let t = Instant::now();
        let scene = edgepoint_proto::scene_from_source(&source, &progress).map_err(|e| anyhow::anyhow!("{e}"))?;
        load_ms.push(t.elapsed().as_secs_f64() * 1e3);
        if i == 0 {
            let big = scene.objects.iter().max_by_key(|o| o.mesh.triangles.len()).context("scene has no objects")?;
            let s = &big.mesh.stats;
            summary = json!({
                "objects": scene.objects.len(),
                "triangles": scene.triangle_count(),
                "largest_object": big.name,
                "input_triangles": s.input_triangles,
                "welded_triangles": s.triangles,
                "degenerate_dropped": s.degenerate_dropped,
                "vertices": s.vertices,
                "edges": s.edges,
                "boundary_edges": s.boundary_edges,
                "non_manifold_edges": s.non_manifold_edges,
            });
        }
        let t = Instant::now();
        let loaded = edgepoint_worker::LoadedScene::build(scene, what.clone(), &progress);
        bvh_ms.push(t.elapsed().as_secs_f64() * 1e3);
        drop(loaded);
    }
    let (l, b) = (crate::stats::median(&load_ms), crate::stats::median(&bvh_ms));
    let out = json!({
        "input": what,
        "mesh": summary,
        "load_weld_ms_median": l,
        "bvh_build_ms_median": b,
        "total_ms_median": l + b,
        "load_weld_ms": load_ms,
        "bvh_build_ms": bvh_ms,
        "threads": rayon::current_num_threads(),
    });
    let table = format!(
        "load {what}: {} triangles ({} edges, {} boundary); parse+weld+adjacency {:.0} ms, BVH {:.0} ms, total {:.0} ms (median of {})\n",
        out["mesh"]["welded_triangles"], out["mesh"]["edges"], out["mesh"]["boundary_edges"], l, b, l + b, a.repeat.max(1)
    );
    crate::emit(a.json, &out, &table);
    Ok(())
}

/// The same mesh in every format, as the files a viewer would send (main file first).
fn format_files(name: &str, ply: &[u8], positions: &[glam::Vec3], triangles: &[[u32; 3]]) -> Vec<(&'static str, Vec<NamedBytes>)> {
    use std::fmt::Write as _;
    let nb = |n: &str, d: Vec<u8>| NamedBytes { name: n.to_string(), data: d };
    let gz = |d: &[u8]| {
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        std::io::Write::write_all(&mut e, d).expect("in memory");
        e.finish().expect("in memory")
    };
    let mut obj = String::new();
    for p in positions {
        let _ = writeln!(obj, "v {} {} {}", p.x, p.y, p.z);
    }
    for t in triangles {
        let _ = writeln!(obj, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    let mut bin: Vec<u8> = Vec::with_capacity(positions.len() * 12 + triangles.len() * 12);
    positions.iter().for_each(|p| p.to_array().iter().for_each(|v| bin.extend(v.to_le_bytes())));
    triangles.iter().flatten().for_each(|i| bin.extend(i.to_le_bytes()));
    let (lo, hi) = positions.iter().fold((glam::Vec3::splat(f32::MAX), glam::Vec3::splat(f32::MIN)), |(l, h), p| (l.min(*p), h.max(*p)));
    let pos_len = positions.len() * 12;
    let gltf = |uri: Option<&str>| {
        let uri = uri.map(|u| format!(r#""uri": "{u}", "#)).unwrap_or_default();
        format!(
            r#"{{"asset": {{"version": "2.0"}}, "scene": 0, "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}],
"meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 1}}]}}],
"buffers": [{{{uri}"byteLength": {}}}],
"bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": {pos_len}}}, {{"buffer": 0, "byteOffset": {pos_len}, "byteLength": {}}}],
"accessors": [{{"bufferView": 0, "componentType": 5126, "count": {}, "type": "VEC3", "min": [{}, {}, {}], "max": [{}, {}, {}]}},
{{"bufferView": 1, "componentType": 5125, "count": {}, "type": "SCALAR"}}]}}"#,
            bin.len(),
            triangles.len() * 12,
            positions.len(),
            lo.x, lo.y, lo.z, hi.x, hi.y, hi.z,
            triangles.len() * 3
        )
    };
    let glb = edgepoint_scene::load::write_glb(gltf(None).as_bytes(), &bin);
    let xml = format!(r#"<scene version="3.0.0"><shape type="ply"><string name="filename" value="{name}"/></shape></scene>"#);
    vec![
        ("ply", vec![nb(name, ply.to_vec())]),
        ("ply.gz", vec![nb(&format!("{name}.gz"), gz(ply))]),
        ("obj", vec![nb("mesh.obj", obj.clone().into_bytes())]),
        ("obj.gz", vec![nb("mesh.obj.gz", gz(obj.as_bytes()))]),
        ("gltf", vec![nb("mesh.gltf", gltf(Some("mesh.bin")).into_bytes()), nb("mesh.bin", bin.clone())]),
        ("glb", vec![nb("mesh.glb", glb)]),
        ("mitsuba xml (ply)", vec![nb("scene.xml", xml.into_bytes()), nb(name, ply.to_vec())]),
    ]
}

fn run_formats(a: &LoadArgs) -> Result<()> {
    let path = a.mesh.as_ref().context("--formats needs --mesh PATH.ply")?;
    let ply = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "mesh.ply".into());
    let base = load_files(&[NamedBytes { name: name.clone(), data: ply.clone() }], &NoProgress).map_err(|e| anyhow::anyhow!("{e}"))?;
    let mesh = &base.objects[0].mesh;
    let sets = format_files(&name, &ply, &mesh.positions, &mesh.triangles);
    // Round-robin over the formats, so load on a shared machine falls on all of them alike.
    let mut ms = vec![Vec::new(); sets.len()];
    let mut tris = vec![0u64; sets.len()];
    for _ in 0..a.repeat.max(1) {
        for (k, (format, files)) in sets.iter().enumerate() {
            let t = Instant::now();
            let s = load_files(files, &NoProgress).map_err(|e| anyhow::anyhow!("{format}: {e}"))?;
            ms[k].push(t.elapsed().as_secs_f64() * 1e3);
            tris[k] = s.objects.iter().filter(|o| o.name != "floor").map(|o| o.mesh.triangles.len() as u64).sum();
        }
    }
    let ply_ms = crate::stats::median(&ms[0]);
    let rows: Vec<_> = sets
        .iter()
        .enumerate()
        .map(|(k, (format, files))| {
            let m = crate::stats::median(&ms[k]);
            let bytes: usize = files.iter().map(|f| f.data.len()).sum();
            json!({"format": format, "bytes": bytes, "triangles": tris[k], "load_ms_median": m, "ratio_to_ply": m / ply_ms, "load_ms": ms[k]})
        })
        .collect();
    let out = json!({"mesh": path.display().to_string(), "repeat": a.repeat.max(1), "threads": rayon::current_num_threads(), "formats": rows});
    let mut table = format!("load (parse + weld + adjacency) of {} in each format, median of {}:\n", path.display(), a.repeat.max(1));
    for r in out["formats"].as_array().expect("array") {
        table.push_str(&format!(
            "  {:<18} {:>11} bytes {:>9.1} ms  {:>5.2}x PLY\n",
            r["format"].as_str().unwrap_or(""),
            r["bytes"],
            r["load_ms_median"].as_f64().unwrap_or(0.0),
            r["ratio_to_ply"].as_f64().unwrap_or(0.0)
        ));
    }
    crate::emit(a.json, &out, &table);
    Ok(())
}
