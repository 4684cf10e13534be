//! Session files the modelling side writes: the pressure protocol.

pub mod protocol;
