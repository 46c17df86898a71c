//! Reference renders through a real in-process worker.
mod common;

use common::Worker;
use edgepoint_proto as pb;
use edgepoint_scene::NoProgress;
use edgepoint_server::image_metrics::psnr;
use edgepoint_server::reference::{render_reference, render_reference_with, ReferenceOptions};
use edgepoint_server::workers::WorkerPool;
use glam::Vec3;
use std::collections::HashMap;
use std::time::Duration;

fn camera_of(name: &str) -> edgepoint_scene::Camera {
    edgepoint_scene::builtin::load(name).unwrap().camera
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_spp_is_the_pixel_centre_ray_whatever_the_batching() {
    // A point light makes the direct shader deterministic, so a pixel's value depends only on
    // its ray: the oracle shades one hand-built centre ray per pixel in a single job.
    let w = Worker::spawn();
    let src = pb::builtin_source("cornell-point");
    let pool = WorkerPool::new(vec![w.url.clone()]).unwrap();
    let d = pool.open(src.clone(), pb::scene_hash(&src));
    let cam = camera_of("cornell-point");
    let (wd, ht) = (24u32, 18u32);
    let params = HashMap::new();
    let opts = ReferenceOptions { batch_size: 37, window: 5, ..Default::default() };
    let img = render_reference_with(&d, &cam, wd, ht, 1, "direct", &params, &NoProgress, &opts).await.unwrap();
    assert_eq!((img.pixels.len(), img.rays), ((wd * ht) as usize, (wd * ht) as u64));

    let f = cam.frame(wd, ht);
    let requests: Vec<pb::ShadeRequest> = (0..wd * ht)
        .map(|p| {
            let (x, y) = (p % wd, p / wd);
            let (o, dir) = f.ray(x as f32 + 0.5, y as f32 + 0.5);
            pb::ShadeRequest { id: p as u64, pixel_x: x, pixel_y: y, origin: Some(o.into()), direction: Some(dir.into()), ..Default::default() }
        })
        .collect();
    let batch = pb::RequestBatch { batch_id: 1, epoch: 0, shader: "direct".into(), requests, seed: 5, ..Default::default() };
    let mut oracle = vec![Vec3::splat(f32::NAN); (wd * ht) as usize];
    d.shade_all([batch], 1, Duration::from_secs(30), |b| {
        for s in &b.samples {
            oracle[s.id as usize] = pb::vec3_or_zero(&s.rgb);
        }
    })
    .await
    .unwrap();
    for (i, (a, b)) in img.pixels.iter().zip(&oracle).enumerate() {
        assert!((*a - *b).abs().max_element() < 1e-6, "pixel {i}: reference {a} vs centre ray {b}");
    }
    // The image is a lit room, not a constant.
    let mean = img.pixels.iter().copied().sum::<Vec3>() / img.pixels.len() as f32;
    assert!(mean.max_element() > 0.01);
    assert!(img.pixels.iter().any(|p| (*p - mean).length() > 0.05));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn more_samples_per_pixel_converge() {
    let w = Worker::spawn();
    let src = pb::builtin_source("cornell");
    let pool = WorkerPool::new(vec![w.url.clone()]).unwrap();
    let d = pool.open(src.clone(), pb::scene_hash(&src));
    let cam = camera_of("cornell");
    let (wd, ht) = (20u32, 16u32);
    let p = HashMap::new();
    let r1 = render_reference(&d, &cam, wd, ht, 1, "direct", &p, &NoProgress).await.unwrap();
    let r16 = render_reference(&d, &cam, wd, ht, 16, "direct", &p, &NoProgress).await.unwrap();
    let opts = ReferenceOptions { seed: 99, ..Default::default() };
    let r64 = render_reference_with(&d, &cam, wd, ht, 64, "direct", &p, &NoProgress, &opts).await.unwrap();
    assert_eq!(r64.rays, (wd * ht * 64) as u64);
    let (e1, e16) = (psnr(&r1.pixels, &r64.pixels), psnr(&r16.pixels, &r64.pixels));
    assert!(e16 > e1 + 3.0, "16 spp ({e16:.1} dB) must be much closer to 64 spp than 1 spp ({e1:.1} dB)");
    assert!(e16 > 25.0, "16 vs 64 spp: {e16:.1} dB");

    // Invalid requests are errors, not panics.
    assert!(render_reference(&d, &cam, 0, 4, 1, "direct", &p, &NoProgress).await.is_err());
    let mut bad = cam;
    bad.fov_y_degrees = f32::NAN;
    assert!(render_reference(&d, &bad, 4, 4, 1, "direct", &p, &NoProgress).await.is_err());
}
