//! TLS from configuration: a server started with a certificate and key (PEM) answers a client
//! that trusts the certificate, and refuses plaintext.

use cathlab_api::pb;
use cathlab_api::pb::simulator_client::SimulatorClient;
use cathlab_tests::*;
use tonic::transport::{Certificate, ClientTlsConfig, Endpoint};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_from_configuration() {
    let dir = temp_dir("tls");
    let certified = rcgen::generate_simple_self_signed(vec!["localhost".to_owned()]).unwrap();
    let cert_pem = certified.cert.pem();
    std::fs::write(dir.join("cert.pem"), &cert_pem).unwrap();
    std::fs::write(dir.join("key.pem"), certified.signing_key.serialize_pem()).unwrap();
    let config = format!(
        "renderer = \"cpu\"\n[tls]\ncert = {:?}\nkey = {:?}\n",
        dir.join("cert.pem"),
        dir.join("key.pem")
    );
    std::fs::write(dir.join("server.toml"), config).unwrap();
    let config_path = dir.join("server.toml");
    let server = ServerProcess::start(
        &dir.join("cathlab.sqlite"),
        &["--config", config_path.to_str().unwrap()],
    );
    let port = server.address.rsplit(':').next().unwrap().to_owned();
    let channel = Endpoint::from_shared(format!("https://localhost:{port}"))
        .unwrap()
        .tls_config(
            ClientTlsConfig::new()
                .ca_certificate(Certificate::from_pem(&cert_pem))
                .domain_name("localhost"),
        )
        .unwrap()
        .connect()
        .await
        .expect("a TLS connection");
    let scenes = SimulatorClient::new(channel)
        .list_scenes(pb::ListScenesRequest {})
        .await
        .unwrap()
        .into_inner();
    assert!(scenes.scenes.iter().any(|s| s.name == "arch_to_cow_lcca"));
    println!("TLS at {}: {} scenes", server.address, scenes.scenes.len());
    // Plaintext HTTP/2 to the TLS port fails.
    let plain = async {
        let mut client = SimulatorClient::connect(server.url()).await?;
        client
            .list_scenes(pb::ListScenesRequest {})
            .await
            .map_err(|e| Box::new(e) as Box<dyn std::error::Error>)?;
        Ok::<_, Box<dyn std::error::Error>>(())
    };
    assert!(
        plain.await.is_err(),
        "plaintext must not work on the TLS port"
    );
}
