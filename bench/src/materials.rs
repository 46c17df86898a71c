//! `edgepoint-bench materials`: the cost of the scattering models (ns per `eval`, `sample`
//! and `pdf` call, per model, on random directions), and the `direct` shader's samples/s on
//! a scene against the shader as it was before materials (`edgepoint_worker::baseline`),
//! measured in this process, interleaved round by round so machine noise hits both alike.
use anyhow::Result;
use edgepoint_scene::material::{Scatter, Scattering};
use edgepoint_scene::Bsdf;
use edgepoint_worker::baseline::shade_batch_before_materials;
use edgepoint_worker::{shade_batch, LoadedScene, RayRequest, ShaderSpec};
use glam::Vec3;
use serde_json::json;
use std::collections::HashMap;
use std::hint::black_box;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct MaterialsArgs {
    /// Calls per model and operation for the per-call costs.
    #[arg(long, default_value_t = 2_000_000)]
    pub calls: usize,
    /// Scene for the shader comparison (built-in name or a .ply / .obj file).
    #[arg(long, default_value = "cornell")]
    pub scene: String,
    /// Requests per shaded batch.
    #[arg(long, default_value_t = 256)]
    pub batch: usize,
    /// Rounds of the shader comparison; each round times both shaders once.
    #[arg(long, default_value_t = 7)]
    pub rounds: usize,
    /// Seconds per shader per round.
    #[arg(long, default_value_t = 1.0)]
    pub seconds: f64,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// One representative of each model (parameters typical of real scenes).
fn models() -> Vec<(&'static str, Scattering)> {
    let gold = (Vec3::new(0.143, 0.374, 1.442), Vec3::new(3.983, 2.385, 1.603));
    let base = Vec3::new(0.6, 0.5, 0.4);
    vec![
        ("lambert", Bsdf::Diffuse.at(base)),
        ("conductor_rough", Bsdf::Conductor { eta: gold.0, k: gold.1, roughness: 0.2 }.at(base)),
        ("conductor_smooth", Bsdf::Conductor { eta: gold.0, k: gold.1, roughness: 0.0 }.at(base)),
        ("dielectric_rough", Bsdf::Dielectric { ior: 1.5, roughness: 0.2 }.at(base)),
        ("dielectric_smooth", Bsdf::Dielectric { ior: 1.5, roughness: 0.0 }.at(base)),
        ("plastic_rough", Bsdf::Plastic { ior: 1.5, roughness: 0.2 }.at(base)),
        ("plastic_smooth", Bsdf::Plastic { ior: 1.5, roughness: 0.0 }.at(base)),
    ]
}

/// Random upper-hemisphere directions and uniform triples (xorshift; cycled through).
fn inputs(n: usize) -> (Vec<Vec3>, Vec<Vec3>) {
    let mut s = 0x2545_f491_4f6c_dd1du64;
    let mut u = move || {
        s ^= s >> 12;
        s ^= s << 25;
        s ^= s >> 27;
        (s.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 40) as f32 / (1u64 << 24) as f32
    };
    let dirs = (0..n)
        .map(|_| {
            let z = u().max(1e-3);
            let r = (1.0 - z * z).sqrt();
            let phi = u() * std::f32::consts::TAU;
            Vec3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect();
    let us = (0..n).map(|_| Vec3::new(u(), u(), u())).collect();
    (dirs, us)
}

/// Nanoseconds per call of `f` over `calls` calls.
fn time_ns(calls: usize, mut f: impl FnMut(usize)) -> f64 {
    let t = Instant::now();
    for i in 0..calls {
        f(i);
    }
    t.elapsed().as_secs_f64() * 1e9 / calls as f64
}

pub fn run(a: MaterialsArgs) -> Result<()> {
    const N: usize = 4096;
    let (dirs, us) = inputs(N);
    let mut rows = Vec::new();
    let mut table = String::from("scattering models, ns per call (random directions)\n");
    for (name, m) in models() {
        let eval = time_ns(a.calls, |i| {
            black_box(m.eval(black_box(dirs[i % N]), dirs[(i + 1) % N]));
        });
        let sample = time_ns(a.calls, |i| {
            black_box(m.sample(black_box(dirs[i % N]), us[i % N]));
        });
        let pdf = time_ns(a.calls, |i| {
            black_box(m.pdf(black_box(dirs[i % N]), dirs[(i + 1) % N]));
        });
        table += &format!("  {name:<18} eval {eval:6.1}  sample {sample:6.1}  pdf {pdf:6.1}\n");
        rows.push(json!({ "model": name, "eval_ns": eval, "sample_ns": sample, "pdf_ns": pdf }));
    }

    // The shader comparison: one thread, the same prepared rays and seeds for both.
    let source = edgepoint_viewer::client::scene_source_from_arg(&a.scene)?;
    let scene = edgepoint_proto::scene_from_source(&source, &edgepoint_scene::NoProgress).map_err(|e| anyhow::anyhow!("{e}"))?;
    let camera = scene.camera;
    let loaded = LoadedScene::build(scene, "bench".into(), &edgepoint_scene::NoProgress);
    let inst = loaded.instances(&loaded.default_transforms());
    let spec = ShaderSpec::parse("direct", &HashMap::new()).map_err(|e| anyhow::anyhow!(e))?;
    let ShaderSpec::Direct(params) = spec.clone() else { unreachable!("parsed as direct") };
    let mut gen = crate::requests::RayGen::new(&camera, 7);
    let prepared: Vec<Vec<RayRequest>> = (0..64).map(|_| gen.batch(a.batch)).collect();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let rate = |before: bool| {
        pool.install(|| {
            let (t, mut n, mut seed) = (Instant::now(), 0u64, 0u64);
            while t.elapsed().as_secs_f64() < a.seconds {
                let reqs = &prepared[seed as usize % prepared.len()];
                seed += 1;
                let out = if before {
                    shade_batch_before_materials(&loaded, &inst, &params, seed, reqs)
                } else {
                    shade_batch(&loaded, &inst, &spec, seed, reqs)
                };
                n += out.samples.len() as u64;
            }
            n as f64 / t.elapsed().as_secs_f64()
        })
    };
    let (mut before, mut after, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
    for round in 0..a.rounds.max(1) {
        // Alternate the order so a drift in machine load favours neither.
        let (b, f) = if round % 2 == 0 {
            let b = rate(true);
            (b, rate(false))
        } else {
            let f = rate(false);
            (rate(true), f)
        };
        before.push(b);
        after.push(f);
        ratios.push(f / b);
    }
    let median = |v: &[f64]| {
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        s[s.len() / 2]
    };
    let ratio = median(&ratios);
    table += &format!(
        "direct shader on {} (1 thread, batch {}): before materials {:.0} samples/s, now {:.0} samples/s, ratio now/before {:.3} (median of {} rounds)\n",
        a.scene,
        a.batch,
        median(&before),
        median(&after),
        ratio,
        ratios.len()
    );
    let out = json!({
        "models": rows,
        "calls": a.calls,
        "direct": {
            "scene": a.scene,
            "batch": a.batch,
            "threads": 1,
            "before_samples_per_s": before,
            "after_samples_per_s": after,
            "ratio_after_over_before": ratios,
            "median_ratio": ratio,
        },
    });
    crate::emit(a.json, &out, &table);
    Ok(())
}
