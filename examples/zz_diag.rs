use std::path::Path;
use tadgs::io::model::Model;
use tadgs::model::deform::sigmoid;
use tadgs::scene::load_scene;
fn main() {
    let run = Path::new("/tmp/exp/static4k");
    let scene = load_scene(&run.join("scene.ron")).unwrap();
    let model = Model::load(&run.join("model.safetensors")).unwrap();
    let dataset = tadgs::data::load(&scene.data).unwrap();
    for &ci in &dataset.test_cameras() {
        let cam = dataset.cameras[ci];
        let mut rows: Vec<(f32, f32, f32, f32, [f32;3])> = model.gaussians.iter().filter_map(|g| {
            let mean = glam::Vec3::from_array(g.position.mean);
            let p = cam.world_to_camera.transform_point3(mean);
            let s = g.scale.d0.map(f32::exp);
            let op = sigmoid(g.opacity.logit);
            if p.z <= 0.01 || op < 0.05 { return None; }
            let smax = s[0].max(s[1]).max(s[2]);
            let pix = cam.fx * smax / p.z;
            Some((pix, p.z, smax, op, g.position.mean))
        }).collect();
        rows.sort_by(|a, b| b.0.partial_cmp(&a.0).unwrap());
        println!("camera {ci}: n={}", rows.len());
        for r in rows.iter().take(5) { println!("  pix {:.0} depth {:.3} scale {:.3} opacity {:.2} at {:?}", r.0, r.1, r.2, r.3, r.4); }
        let mind = dataset.train_cameras().iter().map(|&c| (dataset.cameras[c].center() - cam.center()).length()).fold(f32::MAX, f32::min);
        println!("  nearest training camera {mind:.3}");
    }
}
