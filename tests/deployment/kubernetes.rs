//! The Kubernetes manifests in `deploy/kubernetes/`, checked offline: every document against
//! the schema of its kind (Kubernetes 1.33's strict schemas, Agones 1.61's Fleet and
//! FleetAutoscaler CRD schemas, vendored in `deploy/kubernetes/schemas/` with their
//! licences), the Fleet's pod template also against Kubernetes' PodTemplateSpec; then what no
//! schema sees: the pieces agree with each other and with the server (scenes to warm exist,
//! the sessions counter's name and capacity are the server's, selectors select, references
//! resolve). A malformed value is caught, named by its path.

use std::path::{Path, PathBuf};

use serde::Deserialize;
use serde_json::{Value, json};

fn deploy() -> PathBuf {
    cathlab_tests::repo_root().join("deploy/kubernetes")
}

fn schemas() -> PathBuf {
    deploy().join("schemas")
}

/// The documents of a YAML file, as JSON values.
fn documents(text: &str) -> Vec<Value> {
    serde_yaml_ng::Deserializer::from_str(text)
        .map(|d| Value::deserialize(d).expect("YAML parses"))
        .filter(|v| !v.is_null())
        .collect()
}

/// Every manifest file with its documents.
fn manifests() -> Vec<(String, Vec<Value>)> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(deploy())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "yaml"))
        .collect();
    files.sort();
    files
        .into_iter()
        .map(|p| {
            let text = std::fs::read_to_string(&p).unwrap();
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                documents(&text),
            )
        })
        .collect()
}

/// The vendored schema file of a document's apiVersion and kind.
fn schema_file(document: &Value) -> Option<PathBuf> {
    let api = document["apiVersion"].as_str()?;
    let kind = document["kind"].as_str()?.to_lowercase();
    let (group, version) = api.rsplit_once('/').unwrap_or(("", api));
    let file = match group {
        "agones.dev" | "autoscaling.agones.dev" => schemas().join(format!(
            "agones-1.61/{kind}-{}-{version}.json",
            group.split('.').next().unwrap()
        )),
        "" => schemas().join(format!("kubernetes-v1.33/{kind}-{version}.json")),
        _ => schemas().join(format!(
            "kubernetes-v1.33/{kind}-{}-{version}.json",
            group.split('.').next().unwrap()
        )),
    };
    file.is_file().then_some(file)
}

fn file_uri(path: &Path) -> String {
    format!("file://{}", path.canonicalize().unwrap().display())
}

/// Reads referenced schemas from the vendored files: the Kubernetes kinds refer to
/// `/api/_definitions.json`, which is `kubernetes-v1.33/_definitions.json` here.
struct Vendored;

impl jsonschema::Retrieve for Vendored {
    fn retrieve(
        &self,
        uri: &jsonschema::Uri<String>,
    ) -> Result<Value, Box<dyn std::error::Error + Send + Sync>> {
        let path = uri.path().as_str();
        let file = if path.ends_with("/_definitions.json") {
            schemas().join("kubernetes-v1.33/_definitions.json")
        } else {
            PathBuf::from(path)
        };
        Ok(serde_json::from_str(
            &std::fs::read_to_string(&file).map_err(|e| format!("{}: {e}", file.display()))?,
        )?)
    }
}

/// The schema errors of `document` against `schema` (its relative references resolved from
/// `base`), one line each: the instance path and the message. Agones' CRD schemas are
/// OpenAPI 3.0 (draft-4 style `exclusiveMinimum: true`).
fn errors(schema: &Value, base: &Path, document: &Value) -> Vec<String> {
    let mut options = jsonschema::options()
        .with_base_uri(file_uri(base))
        .with_retriever(Vendored);
    if base.starts_with(schemas().join("agones-1.61")) {
        options = options.with_draft(jsonschema::Draft::Draft4);
    }
    let validator = options
        .build(schema)
        .unwrap_or_else(|e| panic!("{}: {e}", base.display()));
    validator
        .iter_errors(document)
        .map(|e| format!("{}: {e}", e.instance_path()))
        .collect()
}

/// Everything wrong with one document: against its kind's schema and, for a Fleet, its pod
/// template against Kubernetes' PodTemplateSpec.
fn problems(document: &Value) -> Vec<String> {
    let Some(file) = schema_file(document) else {
        return vec![format!(
            "no vendored schema for {} {}",
            document["apiVersion"], document["kind"]
        )];
    };
    let schema: Value = serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    let mut found = errors(&schema, &file, document);
    if document["kind"] == "Fleet" {
        // A schema of its own beside the definitions, referring to them.
        let beside = schemas().join("kubernetes-v1.33/configmap-v1.json");
        let pod = json!({"$ref": "_definitions.json#/$defs/io.k8s.api.core.v1.PodTemplateSpec"});
        found.extend(
            errors(
                &pod,
                &beside,
                &document["spec"]["template"]["spec"]["template"],
            )
            .into_iter()
            .map(|e| format!("/spec/template/spec/template{e}")),
        );
    }
    found
}

fn named<'a>(all: &'a [(String, Vec<Value>)], kind: &str, name: &str) -> &'a Value {
    all.iter()
        .flat_map(|(_, docs)| docs)
        .find(|d| d["kind"] == kind && d["metadata"]["name"] == name)
        .unwrap_or_else(|| panic!("no {kind} {name}"))
}

/// The value after `flag` in a container's args.
fn arg<'a>(args: &'a [Value], flag: &str) -> Vec<&'a str> {
    args.windows(2)
        .filter(|w| w[0] == flag)
        .map(|w| w[1].as_str().unwrap())
        .collect()
}

#[test]
fn every_manifest_matches_its_schema_and_the_pieces_agree() {
    let all = manifests();
    let kinds: Vec<String> = all
        .iter()
        .flat_map(|(_, docs)| docs)
        .map(|d| d["kind"].as_str().unwrap().to_owned())
        .collect();
    for kind in [
        "Fleet",
        "FleetAutoscaler",
        "StatefulSet",
        "Service",
        "Ingress",
    ] {
        assert!(kinds.iter().any(|k| k == kind), "no {kind} in {kinds:?}");
    }
    for (file, docs) in &all {
        for (i, doc) in docs.iter().enumerate() {
            let found = problems(doc);
            assert!(
                found.is_empty(),
                "{file} document {i} ({} {}):\n{}",
                doc["kind"],
                doc["metadata"]["name"],
                found.join("\n")
            );
            assert_eq!(
                doc["metadata"]["namespace"], "cathlab",
                "{file} document {i}"
            );
        }
    }

    // The Fleet and what it runs.
    let fleet = named(&all, "Fleet", "cathlab");
    let gs = &fleet["spec"]["template"]["spec"];
    let container = &gs["template"]["spec"]["containers"][0];
    let args = container["args"].as_array().unwrap();
    assert!(args.iter().any(|a| a == "--agones"));
    let counter = &gs["counters"][cathlab_app::agones::SESSIONS_COUNTER];
    let capacity = counter["capacity"].as_i64().unwrap();
    assert_eq!(
        arg(args, "--max-sessions"),
        [capacity.to_string().as_str()],
        "the counter's capacity is the server's session limit"
    );
    let listen = arg(args, "--listen")[0];
    let port: i64 = listen.rsplit(':').next().unwrap().parse().unwrap();
    assert_eq!(gs["ports"][0]["containerPort"], port);
    assert_eq!(container["ports"][0]["containerPort"], port);
    let catalog =
        cathlab_engine::SceneCatalog::read_dir(&cathlab_tests::repo_root().join("scenes")).unwrap();
    let scenes = catalog.names();
    for scene in arg(args, "--warm") {
        assert!(scenes.contains(&scene), "--warm {scene}: no such scene");
    }
    // Health after warming: the initial delay covers the stroke scene's build.
    assert!(gs["health"]["initialDelaySeconds"].as_i64().unwrap() >= 60);
    // The server's user is not root, as the image's.
    let security = &gs["template"]["spec"]["securityContext"];
    assert_eq!(security["runAsNonRoot"], true);
    assert_eq!(security["runAsUser"], 10001);
    let dockerfile =
        std::fs::read_to_string(cathlab_tests::repo_root().join("deploy/Dockerfile")).unwrap();
    assert!(dockerfile.contains("USER 10001:10001"));
    assert!(
        dockerfile.contains("mesa-vulkan-drivers"),
        "lavapipe in the image"
    );
    // Scraped where the metrics are.
    let annotations = &gs["template"]["metadata"]["annotations"];
    assert_eq!(annotations["prometheus.io/scrape"], "true");
    assert_eq!(annotations["prometheus.io/port"], port.to_string());
    assert_eq!(annotations["prometheus.io/path"], "/metrics");

    // The autoscaler scales that Fleet by that counter.
    let autoscaler = named(&all, "FleetAutoscaler", "cathlab");
    assert_eq!(autoscaler["spec"]["fleetName"], "cathlab");
    assert_eq!(
        autoscaler["spec"]["policy"]["counter"]["key"],
        cathlab_app::agones::SESSIONS_COUNTER
    );

    // The web Service selects the Fleet's pods on the server's port; the Ingress uses it,
    // with TLS for its host.
    let web = named(&all, "Service", "cathlab-web");
    let pod_labels = &gs["template"]["metadata"]["labels"];
    for (k, v) in web["spec"]["selector"].as_object().unwrap() {
        assert_eq!(
            &pod_labels[k], v,
            "the web Service selects the Fleet's pods ({k})"
        );
    }
    assert_eq!(web["spec"]["ports"][0]["targetPort"], port);
    let ingress = named(&all, "Ingress", "cathlab");
    let rule = &ingress["spec"]["rules"][0];
    assert_eq!(
        rule["http"]["paths"][0]["backend"]["service"]["name"],
        "cathlab-web"
    );
    assert_eq!(ingress["spec"]["tls"][0]["hosts"][0], rule["host"]);
    let origin = format!("https://{}", rule["host"].as_str().unwrap());
    assert_eq!(arg(args, "--cors-origin"), [origin.as_str()]);

    // The database URL's secret and the PostgreSQL Service.
    let postgres = named(&all, "StatefulSet", "cathlab-postgres");
    let service = named(&all, "Service", "cathlab-postgres");
    for (k, v) in service["spec"]["selector"].as_object().unwrap() {
        assert_eq!(&postgres["spec"]["template"]["metadata"]["labels"][k], v);
    }
    let env = container["env"].as_array().unwrap();
    assert!(env.iter().any(|e| e["name"] == "CATHLAB_DATABASE_URL"
        && e["valueFrom"]["secretKeyRef"]["name"] == "cathlab-database"));
}

#[test]
fn malformed_values_are_caught_and_named_by_their_path() {
    for (file, document, from, to, path) in [
        // An Agones enum.
        (
            "fleet.yaml",
            0,
            "portPolicy: Dynamic",
            "portPolicy: Dinamic",
            "/spec/template/spec/ports/0/portPolicy",
        ),
        // A number as words.
        (
            "fleet.yaml",
            0,
            "replicas: 2",
            "replicas: two",
            "/spec/replicas",
        ),
        // A misspelt pod field (Kubernetes' schemas are strict).
        (
            "fleet.yaml",
            0,
            "terminationGracePeriodSeconds: 60",
            "terminationGracePeriod: 60",
            "/spec/template/spec/template/spec",
        ),
        // A quantity that is not one.
        (
            "fleet.yaml",
            0,
            "cpu: \"2\"",
            "cpu: [2]",
            "/spec/template/spec/template/spec/containers/0/resources/requests/cpu",
        ),
        // An autoscaler's capacity below its minimum.
        (
            "fleetautoscaler.yaml",
            0,
            "maxCapacity: 400",
            "maxCapacity: 0",
            "/spec/policy/counter/maxCapacity",
        ),
        // A Service port as text.
        (
            "web.yaml",
            0,
            "port: 443",
            "port: \"443\"",
            "/spec/ports/0/port",
        ),
        // A misspelt StatefulSet field.
        (
            "postgres.yaml",
            1,
            "serviceName: cathlab-postgres",
            "serviceNam: cathlab-postgres",
            "/spec",
        ),
    ] {
        let text = std::fs::read_to_string(deploy().join(file)).unwrap();
        assert!(text.contains(from), "{file}: {from}");
        let broken = documents(&text.replacen(from, to, 1));
        let found = problems(&broken[document]);
        assert!(
            found.iter().any(|e| e.starts_with(path)),
            "{file}: {to}: expected an error at {path}, found {found:?}"
        );
        assert!(problems(&documents(&text)[document]).is_empty());
    }
    // A kind with no vendored schema is named, not passed.
    let unknown = documents("apiVersion: example.org/v1\nkind: Gizmo\nmetadata: {name: x}\n");
    assert!(problems(&unknown[0])[0].contains("no vendored schema"));
}
