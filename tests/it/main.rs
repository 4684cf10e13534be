//! Integration tests: one binary, a module per area.

mod bad_input;
mod basis;
mod calibrate;
mod cameras;
mod capture;
mod cli;
mod common;
mod contract;
mod data;
mod docs;
mod export;
mod family;
mod fuzz;
mod geometry;
mod history;
mod images;
mod interval;
mod lab;
mod live;
mod monitor;
mod msvr;
mod pipeline;
mod search;
mod trajectory;
mod triangulate;
mod view;
