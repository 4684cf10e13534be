//! Rendering speed of the virtual capture: a chessboard view, a finger frame, developing (blur,
//! noise, 8-bit) and PNG encoding, and a whole 1280×720 frame pair as `synth` makes it.
//! Target (issue: virtual rig): a pair in well under 100 ms.
//!
//! Run: `cargo bench --bench render`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Point3, Rotation3, Vector3};

use handcap::geometry::WorldFromBoard;
use handcap::synth::camera::RigConfig;
use handcap::synth::image_format::encode_png;
use handcap::synth::plant::Plant;
use handcap::synth::render::{Lighting, Surroundings, View};
use handcap::synth::scene::{Board, Finger};

fn bench(c: &mut Criterion) {
    let rig = RigConfig::default().build(2020);
    let views = [
        View::new(
            rig.left().clone(),
            Lighting::from_seed(1),
            Surroundings::default(),
        ),
        View::new(
            rig.right().clone(),
            Lighting::from_seed(2),
            Surroundings::default(),
        ),
    ];
    let aim = Point3::new(0.0, 0.0, 8.0);
    let toward = (aim - rig.left().pose.centre()).normalize();
    let x = Vector3::x();
    let y = toward.cross(&x);
    let rotation =
        Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[x, y, toward]));
    let board = Board {
        spec: handcap::calib::file::default_board(),
        pose: WorldFromBoard::new(
            rotation,
            (aim - rotation * Vector3::new(40.0, 25.0, 0.0)).coords,
        ),
        markers: Default::default(),
    };
    let plant = Plant::default();
    let finger = Finger::from_centre_line(&plant.centre_line([0.0, 120.0, 200.0]).unwrap(), 8);

    let mut g = c.benchmark_group("render");
    g.sample_size(10);
    g.bench_function("board view", |b| {
        b.iter(|| black_box(views[0].board(&board)))
    });
    g.bench_function("finger view", |b| {
        b.iter(|| black_box(views[0].finger(std::slice::from_ref(&finger))))
    });
    let canvas = views[0].finger(std::slice::from_ref(&finger));
    g.bench_function("develop", |b| {
        b.iter(|| black_box(canvas.clone().develop(1.0, 7, 1)))
    });
    let rgb = canvas.clone().develop(1.0, 7, 1);
    g.bench_function("encode png", |b| {
        b.iter(|| black_box(encode_png(1280, 720, &rgb)))
    });
    g.bench_function("frame pair (render, develop, encode)", |b| {
        b.iter(|| {
            for (k, view) in views.iter().enumerate() {
                let rgb = view
                    .finger(std::slice::from_ref(&finger))
                    .develop(1.0, 7, k as u64);
                black_box(encode_png(1280, 720, &rgb));
            }
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
