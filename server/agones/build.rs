//! Compiles the vendored Agones SDK protos (`proto/sdk/sdk.proto`, `proto/sdk/beta/beta.proto`,
//! Agones 1.61.0, Apache-2.0) with protox (no protoc) into prost messages, a tonic client and,
//! for the recording stand-in, a tonic server.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("proto");
    let files = [root.join("sdk/sdk.proto"), root.join("sdk/beta/beta.proto")];
    println!("cargo:rerun-if-changed={}", root.display());
    let includes = [
        root.join("sdk"),
        root.join("sdk/beta"),
        root.join("googleapis"),
        root.join("grpc-gateway"),
    ];
    let descriptors = protox::compile(&files, &includes)?;
    tonic_prost_build::configure()
        .build_server(true)
        .build_client(true)
        .generate_default_stubs(true)
        .compile_fds(descriptors)?;
    Ok(())
}
