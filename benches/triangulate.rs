//! Speed of `triangulate` per frame, on what webcams give (MJPEG 4:2:0 at quality 85, in the
//! lab of `handcap synth`): JPEG decoding, the marker search (region and sub-pixel fit), a
//! whole pair (read, decode, markers, triangulation and reprojection), and the throughput of
//! 32 pairs on every core, as `handcap triangulate` runs them.
//! Target (issue 16): at least 150 frame pairs per second at 1280×720, decode included.
//!
//! Run: `cargo bench --bench triangulate`. The fit's iterations depend on the frame, so frames
//! each commit renders with its own renderer do not compare: with `HANDCAP_BENCH_FRAMES=DIR`
//! the frames are read from DIR (rendered there when missing), the same bytes for every commit
//! benchmarked against it.

use std::hint::black_box;
use std::path::{Path, PathBuf};

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rayon::prelude::*;

use handcap::image::{decode_into, Buffers, RgbImage};
use handcap::stereo::{Side, StereoRig};
use handcap::synth::camera::RigConfig;
use handcap::synth::capture::Realism;
use handcap::synth::clutter;
use handcap::synth::image_format::ImageFormat;
use handcap::synth::plant::Plant;
use handcap::synth::render::{Lighting, Surroundings, View};
use handcap::synth::scene::Finger;
use handcap::triangulate::marker::{find_markers, MarkerOptions};
use handcap::triangulate::scene::Thumbnail;

/// Reads, decodes and searches both frames, then triangulates and reprojects the tip.
fn pair(rig: &StereoRig, files: [&Path; 2], image: &mut RgbImage, buf: &mut Buffers) -> f64 {
    let mut centres = [[0.0; 2]; 2];
    for (k, f) in files.iter().enumerate() {
        decode_into(f, image, buf).expect("a JPEG");
        centres[k] = find_markers(image, &MarkerOptions::default()).blobs[0].centre_px;
    }
    let p = rig.triangulate(&[centres[0]], &[centres[1]]).unwrap();
    rig.project(Side::Left, &p).unwrap()[0][0] + rig.project(Side::Right, &p).unwrap()[0][0]
}

fn bench(c: &mut Criterion) {
    let rig = RigConfig::default().build(2020);
    let finger = Finger::from_centre_line(
        &Plant::default().centre_line([0.0, 120.0, 200.0]).unwrap(),
        4,
    );
    let dir = tempfile::tempdir().unwrap();
    let kept = std::env::var_os("HANDCAP_BENCH_FRAMES").map(PathBuf::from);
    let base = kept.as_deref().unwrap_or(dir.path());
    std::fs::create_dir_all(base).unwrap();
    let files: Vec<PathBuf> = [(rig.left(), "left"), (rig.right(), "right")]
        .iter()
        .enumerate()
        .map(|(k, (cam, name))| {
            let path = base.join(format!("{name}_00000.jpg"));
            if path.is_file() {
                return path;
            }
            let keep_clear = [500.0, 200.0, 800.0, 500.0];
            let surroundings = Surroundings {
                wall: Some(clutter::wall(1280, 720, k as u64, k == 1, keep_clear)),
                specular: Realism::LAB.specular,
            };
            let view = View::new((*cam).clone(), Lighting::from_seed(k as u64), surroundings);
            let rgb = view
                .finger(std::slice::from_ref(&finger))
                .develop(1.0, 7, k as u64);
            std::fs::write(&path, ImageFormat::WEBCAM.encode(1280, 720, &rgb)).unwrap();
            path
        })
        .collect();
    let cams = rig.stereo();
    let (mut image, mut buf) = (RgbImage::default(), Buffers::default());

    let mut g = c.benchmark_group("triangulate");
    g.sample_size(20);
    g.bench_function("decode jpeg 1280x720", |b| {
        b.iter(|| decode_into(&files[0], &mut image, &mut buf).unwrap())
    });
    decode_into(&files[0], &mut image, &mut buf).unwrap();
    g.bench_function("find markers 1280x720", |b| {
        b.iter(|| black_box(find_markers(&image, &MarkerOptions::default())))
    });
    let first = Thumbnail::of(&image).unwrap();
    g.bench_function("still scene's shift 1280x720 (thumbnail, 12 tiles)", |b| {
        b.iter(|| {
            let thumbnail = Thumbnail::of(&image).unwrap();
            black_box(thumbnail.motion_from(&first).unwrap())
        })
    });
    g.bench_function("frame pair, one core", |b| {
        b.iter(|| black_box(pair(&cams, [&files[0], &files[1]], &mut image, &mut buf)))
    });
    g.throughput(Throughput::Elements(32));
    g.bench_function("32 frame pairs, all cores", |b| {
        b.iter(|| {
            (0..32)
                .into_par_iter()
                .map_init(
                    || (RgbImage::default(), Buffers::default()),
                    |(image, buf), _| pair(&cams, [&files[0], &files[1]], image, buf),
                )
                .sum::<f64>()
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
