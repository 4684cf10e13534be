//! Every `handcap` command, those that call OpenCV (capture, calibration, triangulation, the
//! virtual rig, the demo, boards) included: `handcap` hands these to this binary, so that the
//! modelling commands start without loading OpenCV. Run as `handcap`, never by name.

fn main() -> std::process::ExitCode {
    handcap::cli::main(handcap::cli::run_cameras)
}
