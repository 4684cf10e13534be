//! Round trips between handcap's own camera model (synth renders with it) and OpenCV's (calib
//! and triangulate measure with it), on random points in front of random virtual rigs.

use nalgebra::{Point3, Vector3};
use proptest::prelude::*;

use handcap::stereo::Side;
use handcap::synth::camera::RigConfig;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// A world point seen by both virtual cameras projects to the same pixels through OpenCV,
    /// and OpenCV's undistortion and triangulation bring it back.
    #[test]
    fn project_undistort_triangulate_round_trip(
        seed in 0u64..1000,
        offset in prop::array::uniform3(-25.0..25.0f64),
    ) {
        let rig = RigConfig::default().build(seed);
        let stereo = rig.stereo();
        // A point around the finger's working volume (hand frame = synth's world).
        let world = Point3::new(offset[0], offset[1], 8.0 + offset[2]);
        let left = rig.left().pose.apply(&world);
        let px = [rig.left().project(&world).unwrap(), rig.right().project(&world).unwrap()];

        // Projection: handcap's model and OpenCV's agree.
        for (side, expected) in [(Side::Left, px[0]), (Side::Right, px[1])] {
            let cv = stereo.project(side, &[left.coords]).unwrap()[0];
            prop_assert!((cv[0] - expected[0]).abs() < 1e-6 && (cv[1] - expected[1]).abs() < 1e-6,
                "{side:?}: OpenCV {cv:?}, handcap {expected:?}");
        }
        // Undistortion: OpenCV's normalised coordinates are the point's x/z, y/z.
        let normal = stereo.normalized(Side::Left, &[px[0]]).unwrap()[0];
        prop_assert!((normal[0] - left.x / left.z).abs() < 1e-9);
        prop_assert!((normal[1] - left.y / left.z).abs() < 1e-9);
        let (x, y) = rig.left().intrinsics.undistort(px[0][0], px[0][1]);
        prop_assert!((x - normal[0]).abs() < 1e-9 && (y - normal[1]).abs() < 1e-9);

        // Triangulation returns the point (left camera frame).
        let back: Vector3<f64> = stereo.triangulate(&[px[0]], &[px[1]]).unwrap()[0];
        prop_assert!((back - left.coords).norm() < 1e-6, "{back} vs {}", left.coords);

        // The pose the rig reports agrees with the two cameras' poses.
        let right = rig.right().pose.apply(&world);
        let via = stereo.right_from_left.apply(&left);
        prop_assert!((via - right).norm() < 1e-9);
    }
}
