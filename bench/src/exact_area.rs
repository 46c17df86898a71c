//! `edgepoint-bench exact-area`: the `direct` shader's exact area lights (`area=exact`,
//! issue 15 item 2) against its sampled soft shadows, in this process on one thread: the
//! samples per second of each (CPU time of the shading thread, so other work on the machine
//! does not count) and the sampled images' RMS difference from the exact one (their noise:
//! the exact image has none), over the same camera rays (pixel centres of the scene camera).
use crate::clock::thread_cpu_ms;
use anyhow::Result;
use edgepoint_worker::{shade_batch, LoadedScene, RayRequest, ShaderSpec};
use serde_json::json;
use std::collections::HashMap;

#[derive(clap::Args, Debug)]
pub struct ExactAreaArgs {
    /// Built-in scene name or a scene file (.ply, .obj, Mitsuba .xml, .gltf, .glb; also .gz).
    #[arg(long, default_value = "cornell")]
    pub scene: String,
    /// Image side: the camera's pixel centres of a SIZE × SIZE image are shaded.
    #[arg(long, default_value_t = 64)]
    pub size: u32,
    /// Shadow rays of the sampled runs (repeatable).
    #[arg(long = "rays", default_values_t = [16u32, 64, 256])]
    pub rays: Vec<u32>,
    /// Seeds per sampled run (the noise is averaged over them; the time is per image).
    #[arg(long, default_value_t = 3)]
    pub seeds: u64,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: ExactAreaArgs) -> Result<()> {
    let source = edgepoint_viewer::client::scene_source_from_arg(&a.scene)?;
    let scene = edgepoint_proto::scene_from_source(&source, &edgepoint_scene::NoProgress).map_err(|e| anyhow::anyhow!("{e}"))?;
    let cam = scene.camera.frame(a.size, a.size);
    let reqs: Vec<RayRequest> = (0..a.size * a.size)
        .map(|i| {
            let (o, d) = cam.ray((i % a.size) as f32 + 0.5, (i / a.size) as f32 + 0.5);
            RayRequest { id: i as u64, pixel: [i % a.size, i / a.size], origin: o, direction: d }
        })
        .collect();
    let loaded = LoadedScene::build(scene, "bench".into(), &edgepoint_scene::NoProgress);
    let inst = loaded.instances(&loaded.default_transforms());
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let parse = |kv: &[(&str, f64)]| ShaderSpec::parse("direct", &kv.iter().map(|(k, v)| (k.to_string(), *v)).collect::<HashMap<_, _>>()).map_err(|e| anyhow::anyhow!(e));
    // (CPU ms of one image, the image's linear RGB).
    let shade = |spec: &ShaderSpec, seed: u64| {
        pool.install(|| {
            let t = thread_cpu_ms();
            let out = shade_batch(&loaded, &inst, spec, seed, &reqs);
            (thread_cpu_ms() - t, out.samples.iter().map(|s| s.rgb).collect::<Vec<_>>())
        })
    };
    let (exact_ms, exact) = shade(&parse(&[("area", 1.0)])?, 1);
    let mean = exact.iter().map(|c| c.element_sum() as f64 / 3.0).sum::<f64>() / exact.len() as f64;
    let pixels = reqs.len() as f64;
    let mut rows = Vec::new();
    let mut table = format!("{} {}², one thread: exact {:.1} ms ({:.0} samples/s)\n", a.scene, a.size, exact_ms, pixels / exact_ms * 1e3);
    table += "shadow_rays   ms/image   samples/s   exact/sampled time   RMS difference / mean\n";
    for &k in &a.rays {
        let spec = parse(&[("shadow_rays", k as f64)])?;
        let (mut ms, mut sq) = (0.0, 0.0);
        for seed in 0..a.seeds.max(1) {
            let (t, img) = shade(&spec, 100 + seed);
            ms += t;
            sq += img.iter().zip(&exact).map(|(s, e)| ((*s - *e).length_squared() / 3.0) as f64).sum::<f64>() / pixels;
        }
        let n = a.seeds.max(1) as f64;
        let (ms, rms) = (ms / n, (sq / n).sqrt() / mean);
        table += &format!("{k:>11}   {ms:>8.1}   {:>9.0}   {:>18.2}   {rms:>21.4}\n", pixels / ms * 1e3, exact_ms / ms);
        rows.push(json!({ "shadow_rays": k, "ms_per_image": ms, "samples_per_s": pixels / ms * 1e3, "exact_time_ratio": exact_ms / ms, "rms_relative": rms }));
    }
    let out = json!({
        "scene": a.scene,
        "pixels": reqs.len(),
        "threads": 1,
        "exact": { "ms_per_image": exact_ms, "samples_per_s": pixels / exact_ms * 1e3 },
        "sampled": rows,
    });
    crate::emit(a.json, &out, &table);
    Ok(())
}
