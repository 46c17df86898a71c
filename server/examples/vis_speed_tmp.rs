use edgepoint_server::visibility::Visibility;
fn cpu_ms() -> f64 { let mut t = libc::timespec { tv_sec: 0, tv_nsec: 0 }; unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut t) }; t.tv_sec as f64 * 1e3 + t.tv_nsec as f64 * 1e-6 }
fn main() {
    rayon::ThreadPoolBuilder::new().num_threads(1).build_global().unwrap();
    let names: Vec<String> = std::env::args().skip(1).collect(); if !names.is_empty() { for n in &names { let scene = edgepoint_scene::builtin::load(n).unwrap(); run(&scene, n); } return; } let names = ["cornell", "chains", "rooms", "torus-capsule"];
    for n in names {
        let scene = edgepoint_scene::builtin::load(n).unwrap();
        run(&scene, n);
    }
    let ply = std::fs::read("/work/shared/data/dragon/dragon_vrip.ply").unwrap();
    let files = vec![edgepoint_scene::load::NamedBytes { name: "dragon_vrip.ply".into(), data: ply }];
    let s = edgepoint_scene::builtin::load_with_files("grid-dragon", &files, &edgepoint_scene::NoProgress).unwrap();
    run(&s, "grid-dragon");
}
fn run(scene: &edgepoint_scene::Scene, n: &str) {
    let tf: Vec<_> = scene.objects.iter().map(|o| o.transform).collect();
    for size in [512u32, 1024] {
        let mut vis = Visibility::new(size, size);
        let (lo, hi) = scene.bounds();
        let mut ts = vec![];
        for k in 0..20 {
            let cam = scene.camera.orbit((lo + hi) * 0.5, k as f32 * 0.01);
            let f = cam.frame(size, size);
            let t = cpu_ms();
            let c = vis.update(scene, &tf, &f);
            ts.push(cpu_ms() - t);
            if k == 0 { eprint!("{n} {size}: tris {} covered {} ", c.triangles, c.covered); }
        }
        ts.sort_by(|a, b| a.partial_cmp(b).unwrap());
        eprintln!("median {:.2} ms", ts[10]);
    }
}
