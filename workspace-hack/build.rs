//! Present so the build-dependencies (the host side's features) are part of the build.
fn main() {}
