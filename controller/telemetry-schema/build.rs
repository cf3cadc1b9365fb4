//! Compiles proto/robodeploy/telemetry.proto: its descriptor set (with imports, for MCAP schema
//! records and the Foxglove WebSocket) into OUT_DIR/telemetry.fds, its Rust types into
//! OUT_DIR/robodeploy.rs.

use prost::Message as _;

fn main() {
    let proto = "proto/robodeploy/telemetry.proto";
    println!("cargo:rerun-if-changed={proto}");
    let mut compiler = protox::Compiler::new(["proto"]).expect("the proto include path");
    compiler.include_imports(true).include_source_info(false);
    compiler
        .open_file("robodeploy/telemetry.proto")
        .unwrap_or_else(|e| panic!("{proto}: {e:?}"));
    let fds = compiler.file_descriptor_set();
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR").expect("OUT_DIR"));
    std::fs::write(out.join("telemetry.fds"), fds.encode_to_vec()).expect("writing telemetry.fds");
    prost_build::Config::new()
        .enable_type_names()
        .compile_fds(fds)
        .unwrap_or_else(|e| panic!("generating Rust from {proto}: {e}"));
}
