//! Compiles `soundmap/v1/*.proto` with protox (pure Rust, no system `protoc`).

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let files = ["soundmap/v1/common.proto", "soundmap/v1/robot_link.proto", "soundmap/v1/monitoring.proto"];
    println!("cargo:rerun-if-changed=soundmap");
    for f in &files {
        println!("cargo:rerun-if-changed={f}");
    }
    let fds = protox::compile(files, ["."])?;
    tonic_prost_build::configure().build_server(true).build_client(true).compile_fds(fds)?;
    Ok(())
}
