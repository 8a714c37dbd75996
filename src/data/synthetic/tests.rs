use super::raycast::{AMBIENT, DIFFUSE, LIGHT};
use super::*;

/// A scene with no floor and the given objects, seen by a default ring.
fn scene_with(objects: Vec<SceneObject>) -> SyntheticScene {
    SyntheticScene {
        frames: 5,
        width: 96,
        height: 80,
        cameras: CameraRing {
            count: 4,
            radius: 5.0,
            height: 0.0,
            target: [0.0; 3],
            fov_x_degrees: 40.0,
        },
        held_out: vec![1],
        background: [0.0, 0.0, 0.0],
        floor: None,
        objects,
        supersample: 2,
        foreground_masks: false,
    }
}

fn sphere(radius: f32, colour: [f32; 3], path: Vec<Keyframe>) -> SceneObject {
    SceneObject {
        shape: Shape::Sphere { radius },
        texture: Texture::Solid(colour),
        path,
        spin: 0.0,
        visible: None,
    }
}

fn at(position: [f32; 3]) -> Vec<Keyframe> {
    vec![Keyframe {
        time: 0.0,
        position,
    }]
}

fn pixel_of(camera: &Camera, world: Vec3) -> usize {
    let (u, v, z) = camera.project(world);
    assert!(
        z > 0.0 && u >= 0.0 && v >= 0.0,
        "point in front of the camera"
    );
    let (x, y) = (u as usize, v as usize);
    assert!(x < camera.width as usize && y < camera.height as usize);
    y * camera.width as usize + x
}

#[test]
fn ray_directions_match_the_camera_model() {
    let scene = demo_scene();
    for camera in scene.cameras() {
        let r = camera.rotation().transpose();
        for (u, v) in [(0.25, 0.25), (80.0, 60.0), (159.75, 3.5)] {
            let dir = (r * Vec3::new(
                (u - camera.cx) / camera.fx,
                (v - camera.cy) / camera.fy,
                1.0,
            ))
            .normalize();
            assert!((dir - camera.ray_direction(u, v)).length() < 1e-5);
        }
    }
}

#[test]
fn ring_cameras_look_at_the_target_from_the_ring() {
    let scene = demo_scene();
    let ring = &scene.cameras;
    let target = Vec3::from(ring.target);
    let cameras = scene.cameras();
    assert_eq!(cameras.len(), ring.count);
    for camera in &cameras {
        let offset = camera.center() - target;
        assert!((offset.y - ring.height).abs() < 1e-4);
        assert!((Vec3::new(offset.x, 0.0, offset.z).length() - ring.radius).abs() < 1e-4);
        let (u, v, _) = camera.project(target);
        assert!((u - 80.0).abs() < 1e-3 && (v - 60.0).abs() < 1e-3);
        assert_eq!((camera.width, camera.height), (160, 120));
    }
    // Evenly spaced: neighbouring centres are all the same distance apart.
    let gap = |i: usize| (cameras[i].center() - cameras[(i + 1) % cameras.len()].center()).length();
    for i in 1..cameras.len() {
        assert!((gap(i) - gap(0)).abs() < 1e-4);
    }
}

#[test]
fn sphere_ahead_covers_its_disk_with_its_colour() {
    let colour = [0.8, 0.4, 0.2];
    let (radius, distance) = (0.8, 5.0);
    let scene = scene_with(vec![sphere(radius, colour, at([0.0; 3]))]);
    let camera = Camera::look_at(
        Vec3::new(0.0, 0.0, distance),
        Vec3::ZERO,
        Vec3::Y,
        96,
        80,
        0.7,
    );
    let (image, mask) = scene.render(&camera, 0.0);
    assert_eq!((image.width, image.height), (96, 80));
    assert!(mask.iter().all(|&m| !m), "a static sphere is not dynamic");

    // Silhouette: a disk of angular radius asin(r / d) around the principal point.
    let disk = camera.fx * (radius / distance).asin().tan();
    for y in 0..80 {
        for x in 0..96 {
            let p = image.get(x, y);
            let lit = p.iter().any(|&c| c > 0.0);
            let d = ((x as f32 + 0.5 - camera.cx).powi(2) + (y as f32 + 0.5 - camera.cy).powi(2))
                .sqrt();
            if d < disk - 1.0 {
                assert!(lit, "pixel ({x}, {y}) inside the disk is background");
            } else if d > disk + 1.0 {
                assert_eq!(p, [0.0; 3], "pixel ({x}, {y}) outside the disk is drawn");
            }
        }
    }
    // With one ray per pixel, the drawn pixels are those whose centre ray hits the sphere.
    let mut single = scene.clone();
    single.supersample = 1;
    let covered = single
        .render(&camera, 0.0)
        .0
        .data
        .iter()
        .filter(|p| p[0] > 0.0)
        .count() as f32;
    let area = PI * disk * disk;
    assert!(
        (covered - area).abs() < 0.02 * area,
        "covered {covered} pixels, expected about {area}"
    );

    // Centre: the normal faces the camera, the colour is the shaded texture colour.
    let normal = Vec3::Z;
    let shade = AMBIENT + DIFFUSE * normal.dot(LIGHT.normalize()).max(0.0);
    let centre = image.get(48, 40);
    for c in 0..3 {
        assert!(
            (centre[c] - colour[c] * shade).abs() < 0.01,
            "{centre:?} vs {colour:?} · {shade}"
        );
    }
}

#[test]
fn static_objects_are_not_dynamic_and_moving_ones_are() {
    let mut floor_scene = scene_with(vec![
        sphere(0.5, [0.2, 0.8, 0.2], at([-1.0, 0.0, 0.0])),
        sphere(
            0.5,
            [0.8, 0.2, 0.2],
            vec![
                Keyframe {
                    time: 0.0,
                    position: [1.0, -0.3, 0.0],
                },
                Keyframe {
                    time: 1.0,
                    position: [1.0, 0.3, 0.0],
                },
            ],
        ),
        SceneObject {
            shape: Shape::Box {
                half_extents: [0.3, 0.3, 0.3],
            },
            texture: Texture::Stripes {
                a: [1.0; 3],
                b: [0.2; 3],
                count: 2.0,
            },
            path: at([0.0, 1.0, 0.0]),
            spin: 1.0,
            visible: None,
        },
    ]);
    floor_scene.floor = Some(Floor {
        y: -1.0,
        half_size: 3.0,
        texture: Texture::Solid([0.5; 3]),
    });
    assert!(!floor_scene.is_dynamic(0));
    assert!(floor_scene.is_dynamic(1));
    assert!(floor_scene.is_dynamic(2));
    let camera = Camera::look_at(Vec3::new(0.0, 0.5, 5.0), Vec3::ZERO, Vec3::Y, 96, 80, 1.0);
    let (image, mask, objects) = floor_scene.render_with_objects(&camera, 0.5);
    let still = pixel_of(&camera, Vec3::new(-1.0, 0.0, 0.0));
    let moving = pixel_of(&camera, floor_scene.objects[1].position_at(0.5));
    let spinning = pixel_of(&camera, Vec3::new(0.0, 1.0, 0.0));
    let floor = pixel_of(&camera, Vec3::new(0.0, -1.0, 2.0));
    assert!(!mask[still] && mask[moving] && mask[spinning] && !mask[floor]);
    assert!(!mask[0], "background corner");
    // The object mask (foreground for carving) holds every object, static or not, and
    // neither the floor nor the sky.
    assert!(objects[still] && objects[moving] && objects[spinning]);
    assert!(!objects[floor] && !objects[0]);
    assert!(
        image.data[moving][0] > 0.3 && image.data[moving][1] < 0.2,
        "the moving sphere is drawn there"
    );
    // Every dynamic pixel shows one of the dynamic objects' textures: none is the static green.
    for (pixel, &m) in image.data.iter().zip(&mask) {
        if m {
            assert!(pixel[1] <= pixel[0] + 1e-6, "{pixel:?} is marked dynamic");
        }
    }
    // The moving sphere really moves: its centre pixel at t = 0 is elsewhere.
    assert_ne!(
        pixel_of(&camera, floor_scene.objects[1].position_at(0.0)),
        moving
    );
}

#[test]
fn visibility_window_hides_the_object_outside_it() {
    let mut object = sphere(0.6, [0.9, 0.9, 0.1], at([0.0; 3]));
    object.visible = Some((0.3, 0.7));
    let scene = scene_with(vec![object]);
    assert!(scene.is_dynamic(0));
    let camera = scene.cameras()[0];
    let centre = pixel_of(&camera, Vec3::ZERO);
    for (t, shown) in [
        (0.0, false),
        (0.29, false),
        (0.3, true),
        (0.5, true),
        (0.7, true),
        (0.71, false),
        (1.0, false),
    ] {
        let (image, mask) = scene.render(&camera, t);
        assert_eq!(image.data[centre][0] > 0.3, shown, "t = {t}");
        assert_eq!(mask[centre], shown, "t = {t}");
        if !shown {
            assert!(image.data.iter().all(|p| *p == [0.0; 3]) && mask.iter().all(|&m| !m));
        }
    }
    // A window covering all of [0, 1] does not make a static object dynamic.
    let mut always = scene.clone();
    always.objects[0].visible = Some((0.0, 1.0));
    assert!(!always.is_dynamic(0));
}

#[test]
fn spinning_texture_moves_with_the_object() {
    let object = SceneObject {
        shape: Shape::Sphere { radius: 1.0 },
        texture: Texture::Stripes {
            a: [1.0, 0.0, 0.0],
            b: [0.0, 0.0, 1.0],
            count: 3.0,
        },
        path: at([0.0; 3]),
        spin: PI / 3.0, // half a stripe pair per unit time: colours swap
        visible: None,
    };
    let scene = scene_with(vec![object]);
    let camera = scene.cameras()[0];
    let (before, _) = scene.render(&camera, 0.0);
    let (after, mask) = scene.render(&camera, 1.0);
    let probe = pixel_of(&camera, Vec3::new(0.55, 0.0, 0.8));
    let (b, a) = (before.data[probe], after.data[probe]);
    assert!(
        (b[0] > b[2]) != (a[0] > a[2]),
        "stripe colour swaps: {b:?} → {a:?}"
    );
    assert!(mask[probe]);
}

#[test]
fn path_interpolation() {
    let object = SceneObject {
        shape: Shape::Sphere { radius: 0.1 },
        texture: Texture::Solid([1.0; 3]),
        path: vec![
            Keyframe {
                time: 0.2,
                position: [0.0, 0.0, 0.0],
            },
            Keyframe {
                time: 0.5,
                position: [3.0, 1.0, 0.0],
            },
            Keyframe {
                time: 0.6,
                position: [4.0, 0.0, 2.0],
            },
        ],
        spin: 0.0,
        visible: None,
    };
    for key in &object.path {
        assert!((object.position_at(key.time) - Vec3::from(key.position)).length() < 1e-5);
    }
    assert_eq!(object.position_at(0.0), Vec3::ZERO);
    assert_eq!(object.position_at(f32::NAN), Vec3::ZERO);
    assert_eq!(object.position_at(1.0), Vec3::new(4.0, 0.0, 2.0));
    // Continuous across keyframes.
    let e = 1e-4;
    assert!((object.position_at(0.5 - e) - object.position_at(0.5 + e)).length() < 1e-2);
    // Two keyframes: linear.
    let linear = SceneObject {
        path: object.path[..2].to_vec(),
        ..object.clone()
    };
    assert!((linear.position_at(0.35) - Vec3::new(1.5, 0.5, 0.0)).length() < 1e-5);
    assert!(object.is_dynamic());
    let still = SceneObject {
        path: object.path[..1].to_vec(),
        ..object
    };
    assert!(!still.is_dynamic());
}

#[test]
fn validate_names_the_offending_field() {
    assert_eq!(demo_scene().validate(), Ok(()));
    type Edit = fn(&mut SyntheticScene);
    let cases: &[(&str, Edit)] = &[
        ("frames", |s| s.frames = 1),
        ("width", |s| s.width = 0),
        ("height", |s| s.height = 0),
        ("supersample", |s| s.supersample = 0),
        ("cameras.count", |s| s.cameras.count = 1),
        ("cameras.radius", |s| s.cameras.radius = 0.0),
        ("cameras.fov_x_degrees", |s| s.cameras.fov_x_degrees = 180.0),
        ("cameras.target", |s| s.cameras.target[1] = f32::NAN),
        ("held_out[1]", |s| s.held_out = vec![2, 16]),
        ("held_out", |s| s.held_out = vec![3, 3]),
        ("held_out", |s| s.held_out = (0..16).collect()),
        ("background", |s| s.background = [1.2, 0.0, 0.0]),
        ("floor.half_size", |s| {
            s.floor.as_mut().unwrap().half_size = -1.0
        }),
        ("floor.texture.cells", |s| {
            s.floor.as_mut().unwrap().texture = Texture::Checker {
                a: [0.0; 3],
                b: [1.0; 3],
                cells: 0.0,
            }
        }),
        ("objects[1].shape.radius", |s| {
            s.objects[1].shape = Shape::Sphere { radius: 0.0 }
        }),
        ("objects[0].shape.half_extents", |s| {
            s.objects[0].shape = Shape::Box {
                half_extents: [0.1, -0.1, 0.1],
            }
        }),
        ("objects[2].texture.a", |s| {
            s.objects[2].texture = Texture::Checker {
                a: [2.0; 3],
                b: [0.0; 3],
                cells: 1.0,
            }
        }),
        ("objects[3].texture.count", |s| {
            s.objects[3].texture = Texture::Stripes {
                a: [1.0; 3],
                b: [0.0; 3],
                count: 2.5,
            }
        }),
        ("objects[4].texture", |s| {
            s.objects[4].texture = Texture::Solid([-0.1, 0.0, 0.0])
        }),
        ("objects[2].path[2].time", |s| {
            s.objects[2].path[2].time = 0.1
        }),
        ("objects[2].path[1].time", |s| {
            s.objects[2].path[1].time = 0.0
        }),
        ("objects[0].path", |s| s.objects[0].path.clear()),
        ("objects[0].path[0].position", |s| {
            s.objects[0].path[0].position[0] = f32::INFINITY
        }),
        ("objects[3].spin", |s| s.objects[3].spin = f32::NAN),
        ("objects[4].visible", |s| {
            s.objects[4].visible = Some((0.7, 0.3))
        }),
    ];
    for (field, edit) in cases {
        let mut scene = demo_scene();
        edit(&mut scene);
        let error = scene.validate().expect_err(field);
        assert_eq!(&error.path, field, "{error}");
        assert_eq!(scene.build().map(|_| ()), Err(error.to_string()));
    }
}

#[test]
fn build_renders_every_camera_and_frame() {
    let mut scene = demo_scene();
    scene.frames = 3;
    scene.width = 32;
    scene.height = 24;
    scene.supersample = 1;
    let dataset = scene.build().expect("valid scene");
    assert_eq!(dataset.frame_count, 3);
    assert_eq!(dataset.cameras.len(), 16);
    assert_eq!(
        dataset.train_cameras(),
        (0..16).filter(|&c| c != 5).collect::<Vec<_>>()
    );
    assert_eq!(dataset.test_cameras(), vec![5]);
    assert_eq!(dataset.train.len(), 15 * 3);
    assert_eq!(dataset.test.len(), 3);
    for view in dataset.train.iter().chain(&dataset.test) {
        assert_eq!(view.image.dimensions(), (32, 24));
        let mask = view.dynamic_mask.as_ref().expect("masks");
        assert_eq!(mask.len(), 32 * 24);
        assert_eq!(view.time, dataset.frame_time(view.frame));
        // The same as rendering that view alone (quantised to 8 bits).
        let alone = scene.render(&dataset.cameras[view.camera], view.time);
        assert_eq!(
            (&alone.0.to_rgb8(), &alone.1),
            (&*view.image.pixels().unwrap(), mask)
        );
    }
}

#[test]
fn demo_scene_round_trips_through_ron() {
    let scene = demo_scene();
    let text =
        ron::ser::to_string_pretty(&scene, ron::ser::PrettyConfig::default()).expect("serialises");
    let back: SyntheticScene = ron::from_str(&text).expect("deserialises");
    assert_eq!(back, scene);
    // Defaults and unknown fields.
    let minimal = text.replace("supersample: 2,", "");
    assert_ne!(minimal, text);
    assert_eq!(
        ron::from_str::<SyntheticScene>(&minimal).expect("default supersample"),
        scene
    );
    let typo = text.replace("supersample:", "super_sample:");
    assert!(ron::from_str::<SyntheticScene>(&typo).is_err());
}

#[test]
fn demo_objects_stay_in_every_view_and_move_everywhere() {
    let scene = demo_scene();
    assert_eq!(
        (0..scene.objects.len())
            .map(|i| scene.is_dynamic(i))
            .collect::<Vec<_>>(),
        [false, false, true, true, true]
    );
    let cameras = scene.cameras();
    // Every object's bounding sphere projects inside every image, at every frame, with a margin.
    let directions: Vec<Vec3> = (-1..=1)
        .flat_map(|x| {
            (-1..=1)
                .flat_map(move |y| (-1..=1).map(move |z| Vec3::new(x as f32, y as f32, z as f32)))
        })
        .filter(|d| *d != Vec3::ZERO)
        .map(|d| d.normalize())
        .collect();
    for object in &scene.objects {
        let bound = match &object.shape {
            Shape::Sphere { radius } => *radius,
            Shape::Box { half_extents } => Vec3::from(*half_extents).length(),
        };
        for f in 0..scene.frames {
            let center = object.position_at(f as f32 / (scene.frames - 1) as f32);
            for camera in &cameras {
                for d in &directions {
                    let (u, v, z) = camera.project(center + bound * *d);
                    assert!(z > 0.5, "in front");
                    assert!(
                        u > 4.0 && u < 156.0 && v > 4.0 && v < 116.0,
                        "({u}, {v}) at frame {f}"
                    );
                }
            }
        }
    }
    // At low resolution, every view of every frame has dynamic pixels, and colours stay in range.
    let mut small = scene.clone();
    small.width = 80;
    small.height = 60;
    small.supersample = 1;
    let dataset = small.build().expect("valid");
    for view in dataset.train.iter().chain(&dataset.test) {
        let mask = view.dynamic_mask.as_ref().unwrap();
        assert!(mask.iter().filter(|&&m| m).count() > 20);
    }
}

/// Writes demo frames to /tmp for a visual check:
/// `cargo test --lib data::synthetic -- --ignored --nocapture`.
#[test]
#[ignore]
fn write_demo_frames() {
    let scene = demo_scene();
    let start = std::time::Instant::now();
    let dataset = scene.build().expect("valid");
    println!("demo build: {:.2} s", start.elapsed().as_secs_f64());
    let (w, h) = (scene.width as usize, scene.height as usize);
    let view_of = |c: usize, f: usize| {
        dataset
            .train
            .iter()
            .chain(&dataset.test)
            .find(|v| v.camera == c && v.frame == f)
            .expect("every camera and frame is rendered")
    };
    view_of(0, 30)
        .to_image()
        .unwrap()
        .save_png(std::path::Path::new("/tmp/demo_frame.png"))
        .expect("writes");
    // A contact sheet: cameras 0, 2, 4, 6 down, frames 0, 20, 30, 40, 59 across, and the
    // masks of camera 0 underneath.
    let frames = [0, 20, 30, 40, 59];
    let rows = [0, 2, 4, 6];
    let mut sheet = Image::filled(w * frames.len(), h * (rows.len() + 1), [0.0; 3]);
    for (col, &f) in frames.iter().enumerate() {
        for (row, &c) in rows.iter().enumerate() {
            let image = view_of(c, f).to_image().unwrap();
            for y in 0..h {
                for x in 0..w {
                    sheet.data[(row * h + y) * sheet.width + col * w + x] = image.get(x, y);
                }
            }
        }
        let mask = view_of(0, f).dynamic_mask.as_ref().expect("masks");
        for y in 0..h {
            for x in 0..w {
                let v = if mask[y * w + x] { 1.0 } else { 0.0 };
                sheet.data[(rows.len() * h + y) * sheet.width + col * w + x] = [v; 3];
            }
        }
    }
    sheet
        .save_png(std::path::Path::new("/tmp/demo_sheet.png"))
        .expect("writes");
    let text = ron::ser::to_string_pretty(&scene, ron::ser::PrettyConfig::default()).unwrap();
    std::fs::write("/tmp/demo_scene.ron", text).expect("writes");
}
