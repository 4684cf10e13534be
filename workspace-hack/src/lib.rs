//! No code: this crate only enables the union of its dependencies' features (see its
//! Cargo.toml), so every build of the workspace compiles each shared dependency once.
