//! strata-terrain's integration tests, one module per file beside this one,
//! in one test binary. Run one file's tests with
//! `cargo test -p strata-terrain --test integration -- mesh_lod::`.

mod mesh_common;

mod codec_props;
mod contour;
mod edit_rules;
mod gen_golden;
mod mesh_api;
mod mesh_determinism;
mod mesh_hash_spec;
mod mesh_layered;
mod mesh_lod;
mod mesh_seams;
mod mesh_topology;
mod protocol_doc_examples;
mod wire_bytes;
