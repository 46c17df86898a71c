//! The built-in scenes after paper 000's through the whole system (a viewer's session on
//! the Renderer service with a real shader worker): `grid-dragon` travels as its
//! description plus the dragon's PLY bytes (found in the shared data directory on the
//! viewer's side; the worker needs no data), the procedural ones by name. Frames with
//! samples arrive for each.
mod common;

use common::{open, spawn_renderer, start_msg, Worker};
use edgepoint_proto as pb;

async fn frames_arrive(source: pb::SceneSource, objects: usize) {
    let w = Worker::spawn();
    let (addr, _h) = spawn_renderer(vec![w.url.clone()], 2).await;
    let mut v = open(&addr, start_msg(source.clone(), 48, 32)).await.unwrap();
    let st = v.started().await;
    assert_eq!(st.scene_hash, pb::scene_hash(&source));
    assert_eq!(st.objects.len(), objects);
    let f = v.frame_with_samples(120).await;
    assert_eq!((f.width, f.height), (48, 32));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grid_dragon_is_sent_with_its_data_and_rendered() {
    let files = edgepoint_scene::data::builtin_files("grid-dragon", None)
        .unwrap()
        .expect("grid-dragon is made from data");
    let source = pb::files_source(files.into_iter().map(|f| (f.name, f.data)).collect());
    frames_arrive(source, 3).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn procedural_scenes_are_rendered() {
    for (name, objects) in [("torus-capsule", 4), ("chains", 33)] {
        frames_arrive(pb::builtin_source(name), objects).await;
    }
}
