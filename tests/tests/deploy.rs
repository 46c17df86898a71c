//! The deployment files agree with the binaries: every manifest in deploy/ parses, every
//! container's command line is accepted by the binary's own clap parser (and by its
//! exposure policy), ports, names, labels and selectors match across the Deployments,
//! Services, the HorizontalPodAutoscaler and the NetworkPolicy, the renderer's DNS
//! discovery names the headless worker Service and its port, mounted secrets hold the files
//! the flags name, and the compose file and the Dockerfile are wired the same way.
//!
//! The container image itself is not built here (no container engine on the CI machine);
//! these checks are what can be verified without one.
use clap::Parser;
use edgepoint_proto::net::{check_exposure, check_metrics_exposure, check_worker_exposure, Protection};
use edgepoint_server::cli::ServerArgs;
use edgepoint_server::workers::WorkerAddr;
use edgepoint_worker::cli::WorkerArgs;
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use yaml_rust2::{Yaml, YamlLoader};

fn deploy_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy")
}

fn load(path: &Path) -> Vec<Yaml> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    YamlLoader::load_from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn s<'a>(y: &'a Yaml, what: &str) -> &'a str {
    y.as_str().unwrap_or_else(|| panic!("{what} should be a string, is {y:?}"))
}

fn list<'a>(y: &'a Yaml, what: &str) -> &'a Vec<Yaml> {
    y.as_vec().unwrap_or_else(|| panic!("{what} should be a list, is {y:?}"))
}

/// A YAML map of strings (labels, selectors) as a sorted map.
fn labels(y: &Yaml) -> BTreeMap<String, String> {
    y.as_hash()
        .map(|h| h.iter().map(|(k, v)| (s(k, "label").to_string(), v.as_str().map(String::from).unwrap_or_else(|| format!("{v:?}")))).collect())
        .unwrap_or_default()
}

fn selects(selector: &BTreeMap<String, String>, pod: &BTreeMap<String, String>) -> bool {
    !selector.is_empty() && selector.iter().all(|(k, v)| pod.get(k) == Some(v))
}

fn strings(y: &Yaml, what: &str) -> Vec<String> {
    list(y, what)
        .iter()
        .map(|a| match a {
            Yaml::String(s) => s.clone(),
            Yaml::Integer(i) => i.to_string(),
            other => panic!("{what}: unexpected {other:?}"),
        })
        .collect()
}

fn port_of(addr: &str) -> u16 {
    addr.parse::<SocketAddr>().unwrap_or_else(|e| panic!("'{addr}' is not host:port: {e}")).port()
}

/// Every Kubernetes object in deploy/k8s, by (kind, name), with the file it came from.
fn k8s() -> BTreeMap<(String, String), (Yaml, String)> {
    let mut out = BTreeMap::new();
    let mut files: Vec<_> = std::fs::read_dir(deploy_dir().join("k8s")).unwrap().map(|e| e.unwrap().path()).collect();
    files.sort();
    for f in files.iter().filter(|f| f.extension().is_some_and(|e| e == "yaml" || e == "yml")) {
        let name = f.file_name().unwrap().to_string_lossy().to_string();
        if name == "kustomization.yaml" {
            continue;
        }
        for doc in load(f) {
            let kind = s(&doc["kind"], "kind").to_string();
            let obj = s(&doc["metadata"]["name"], "metadata.name").to_string();
            assert!(doc["apiVersion"].as_str().is_some(), "{name}: {kind} {obj} has no apiVersion");
            if kind != "Namespace" {
                assert_eq!(doc["metadata"]["namespace"].as_str(), Some("edgepoint"), "{name}: {kind} {obj} namespace");
            }
            assert!(out.insert((kind.clone(), obj.clone()), (doc, name.clone())).is_none(), "{kind} {obj} defined twice");
        }
    }
    out
}

fn get<'a>(objs: &'a BTreeMap<(String, String), (Yaml, String)>, kind: &str, name: &str) -> &'a Yaml {
    &objs.get(&(kind.to_string(), name.to_string())).unwrap_or_else(|| panic!("no {kind} named {name} in deploy/k8s")).0
}

/// The one container of a Deployment, and its pod template labels.
fn container(dep: &Yaml) -> (&Yaml, BTreeMap<String, String>) {
    let tpl = &dep["spec"]["template"];
    let pod = labels(&tpl["metadata"]["labels"]);
    let sel = labels(&dep["spec"]["selector"]["matchLabels"]);
    assert!(selects(&sel, &pod), "the Deployment's selector {sel:?} must match its pods {pod:?}");
    let cs = list(&tpl["spec"]["containers"], "containers");
    assert_eq!(cs.len(), 1, "one container per pod");
    (&cs[0], pod)
}

/// The command line of a container: command + args.
fn argv(c: &Yaml) -> Vec<String> {
    let mut v = strings(&c["command"], "command");
    if !c["args"].is_badvalue() {
        v.extend(strings(&c["args"], "args"));
    }
    v
}

fn named_port(c: &Yaml, name: &str) -> u16 {
    list(&c["ports"], "ports")
        .iter()
        .find(|p| p["name"].as_str() == Some(name))
        .and_then(|p| p["containerPort"].as_i64())
        .unwrap_or_else(|| panic!("no container port named {name}")) as u16
}

/// A Service (or probe) port reference: a number, or the name of a container port.
fn resolve_port(y: &Yaml, c: &Yaml) -> u16 {
    match y {
        Yaml::Integer(i) => *i as u16,
        Yaml::String(n) => named_port(c, n),
        other => panic!("bad port reference {other:?}"),
    }
}

fn cpus(y: &Yaml) -> f64 {
    match y {
        Yaml::Integer(i) => *i as f64,
        Yaml::Real(r) => r.parse().unwrap(),
        Yaml::String(q) => match q.strip_suffix('m') {
            Some(m) => m.parse::<f64>().unwrap() / 1000.0,
            None => q.parse().unwrap(),
        },
        other => panic!("bad CPU quantity {other:?}"),
    }
}

fn prometheus_port(dep: &Yaml) -> u16 {
    let a = &dep["spec"]["template"]["metadata"]["annotations"];
    assert_eq!(a["prometheus.io/scrape"].as_str(), Some("true"));
    assert_eq!(a["prometheus.io/path"].as_str(), Some("/metrics"));
    s(&a["prometheus.io/port"], "prometheus.io/port").parse().unwrap()
}

#[test]
fn every_manifest_parses_and_the_kustomization_lists_them_all() {
    let dir = deploy_dir().join("k8s");
    let objs = k8s();
    let kinds: Vec<(&str, &str)> = objs.keys().map(|(k, n)| (k.as_str(), n.as_str())).collect();
    for want in [
        ("Namespace", "edgepoint"),
        ("Deployment", "edgepoint-worker"),
        ("Service", "edgepoint-worker"),
        ("HorizontalPodAutoscaler", "edgepoint-worker"),
        ("NetworkPolicy", "edgepoint-worker"),
        ("Deployment", "edgepoint-server"),
        ("Service", "edgepoint-server"),
    ] {
        assert!(kinds.contains(&want), "missing {want:?} in {kinds:?}");
    }
    let kust = &load(&dir.join("kustomization.yaml"))[0];
    let mut listed: Vec<String> = strings(&kust["resources"], "resources");
    listed.sort();
    let mut files: Vec<String> = objs.values().map(|(_, f)| f.clone()).collect();
    files.sort();
    files.dedup();
    assert_eq!(listed, files, "kustomization.yaml must list every manifest");
    assert_eq!(kust["namespace"].as_str(), Some("edgepoint"));
    load(&deploy_dir().join("compose.yaml"));
}

#[test]
fn worker_manifests_agree_with_the_worker_binary() {
    let objs = k8s();
    let dep = get(&objs, "Deployment", "edgepoint-worker");
    let (c, pod) = container(dep);
    let argv = argv(c);
    assert_eq!(argv[0], edgepoint_viewer::local::WORKER_BIN);
    let args = WorkerArgs::try_parse_from(&argv).unwrap_or_else(|e| panic!("edgepoint-worker rejects {argv:?}: {e}"));
    let listen: SocketAddr = args.listen.parse().unwrap();
    check_worker_exposure(listen, args.tls_cert.is_some(), args.token_file.is_some() || args.tls_client_ca.is_some(), args.insecure)
        .unwrap_or_else(|e| panic!("the worker would refuse to start: {e}"));
    check_metrics_exposure(args.metrics_listen.as_deref().expect("metrics").parse().unwrap(), args.metrics_public)
        .unwrap_or_else(|e| panic!("the worker would refuse to start: {e}"));
    let token = args.token_file.as_ref().expect("workers authenticate the renderer").display().to_string();
    let mounts = list(&c["volumeMounts"], "volumeMounts");
    let vol = mounts.iter().find(|m| token.starts_with(&format!("{}/", s(&m["mountPath"], "mountPath")))).expect("the token file is mounted");
    let volumes = list(&dep["spec"]["template"]["spec"]["volumes"], "volumes");
    let v = volumes.iter().find(|v| v["name"] == vol["name"]).expect("its volume");
    assert_eq!(v["secret"]["secretName"].as_str(), Some("edgepoint-worker-token"));
    let grpc = named_port(c, "grpc");
    assert_eq!(listen.port(), grpc, "--listen port == containerPort grpc");
    let metrics = port_of(args.metrics_listen.as_deref().expect("workers export metrics"));
    assert_eq!(metrics, named_port(c, "metrics"));
    assert_eq!(prometheus_port(dep), metrics);
    // Probes hit the gRPC health service on the plaintext port.
    for probe in ["readinessProbe", "livenessProbe"] {
        assert_eq!(resolve_port(&c[probe]["grpc"]["port"], c), grpc, "{probe}");
    }
    // Shading threads fit the CPUs the pod may use, and the HPA has a request to scale on.
    let threads = args.threads.expect("--threads set to the CPU limit") as f64;
    assert!(threads <= cpus(&c["resources"]["limits"]["cpu"]), "--threads {threads} above the CPU limit");
    assert!(cpus(&c["resources"]["requests"]["cpu"]) > 0.0);

    // The headless Service selects these pods on the gRPC port.
    let svc = get(&objs, "Service", "edgepoint-worker");
    assert_eq!(svc["spec"]["clusterIP"].as_str(), Some("None"), "the worker Service must be headless (one DNS record per pod)");
    assert!(selects(&labels(&svc["spec"]["selector"]), &pod));
    let ports = list(&svc["spec"]["ports"], "ports");
    assert_eq!(ports.len(), 1);
    assert_eq!(ports[0]["port"].as_i64(), Some(grpc as i64), "headless Services resolve to pod IPs: port must equal the pod port");
    assert_eq!(resolve_port(&ports[0]["targetPort"], c), grpc);

    // The autoscaler scales this Deployment on CPU.
    let hpa = get(&objs, "HorizontalPodAutoscaler", "edgepoint-worker");
    assert_eq!(s(&hpa["apiVersion"], "apiVersion"), "autoscaling/v2");
    let target = &hpa["spec"]["scaleTargetRef"];
    assert_eq!((target["kind"].as_str(), target["name"].as_str()), (Some("Deployment"), Some("edgepoint-worker")));
    let m = &list(&hpa["spec"]["metrics"], "metrics")[0];
    assert_eq!((m["type"].as_str(), m["resource"]["name"].as_str()), (Some("Resource"), Some("cpu")));
    let (lo, hi) = (hpa["spec"]["minReplicas"].as_i64().unwrap(), hpa["spec"]["maxReplicas"].as_i64().unwrap());
    assert!(1 <= lo && lo <= hi, "replicas {lo}..{hi}");

    // Only the renderer reaches the plaintext gRPC port.
    let np = get(&objs, "NetworkPolicy", "edgepoint-worker");
    assert!(selects(&labels(&np["spec"]["podSelector"]["matchLabels"]), &pod));
    let (_, server_pod) = container(get(&objs, "Deployment", "edgepoint-server"));
    let rules = list(&np["spec"]["ingress"], "ingress");
    let grpc_rule = rules
        .iter()
        .find(|r| list(&r["ports"], "ports").iter().any(|p| p["port"].as_i64() == Some(grpc as i64)))
        .expect("an ingress rule for the gRPC port");
    let from = list(&grpc_rule["from"], "from");
    assert!(from.iter().all(|f| selects(&labels(&f["podSelector"]["matchLabels"]), &server_pod)), "gRPC admitted from the renderer only");
    assert!(rules.iter().any(|r| list(&r["ports"], "ports").iter().any(|p| p["port"].as_i64() == Some(metrics as i64))));
}

#[test]
fn server_manifests_agree_with_the_server_binary() {
    let objs = k8s();
    let dep = get(&objs, "Deployment", "edgepoint-server");
    let (c, pod) = container(dep);
    let argv = argv(c);
    assert_eq!(argv[0], edgepoint_viewer::local::SERVER_BIN);
    let args = ServerArgs::try_parse_from(&argv).unwrap_or_else(|e| panic!("edgepoint-server rejects {argv:?}: {e}"));
    let listen: SocketAddr = args.listen.parse().unwrap();
    check_exposure(listen, Protection { tls: args.tls_cert.is_some(), token: Some(args.token_file.is_some()), insecure: args.insecure })
        .unwrap_or_else(|e| panic!("the server would refuse to start: {e}"));
    check_metrics_exposure(args.metrics_listen.as_deref().expect("metrics").parse().unwrap(), args.metrics_public)
        .unwrap_or_else(|e| panic!("the server would refuse to start: {e}"));
    assert!(!args.insecure, "the renderer faces viewers: TLS and tokens, not --insecure");
    let grpc = named_port(c, "grpc");
    assert_eq!(listen.port(), grpc);
    let metrics = port_of(args.metrics_listen.as_deref().expect("the renderer exports metrics"));
    assert_eq!(metrics, named_port(c, "metrics"));
    assert_eq!(prometheus_port(dep), metrics);
    assert_eq!(resolve_port(&c["readinessProbe"]["httpGet"]["port"], c), metrics, "TLS port: probe the metrics port");
    assert_eq!(c["readinessProbe"]["httpGet"]["path"].as_str(), Some("/metrics"));

    // DNS discovery names the headless worker Service, in this namespace, on its port.
    assert_eq!(args.worker_dns.len(), 1, "{:?}", args.worker_dns);
    let dns = WorkerAddr::parse(&args.worker_dns[0]).unwrap();
    let mut parts = dns.host.split('.');
    let (svc_name, ns) = (parts.next().unwrap(), parts.next().unwrap_or("edgepoint"));
    assert_eq!(ns, "edgepoint", "{}", dns.host);
    assert!(dns.host == format!("{svc_name}.{ns}") || dns.host.starts_with(&format!("{svc_name}.{ns}.svc")), "{}", dns.host);
    let workers = get(&objs, "Service", svc_name);
    assert_eq!(workers["spec"]["clusterIP"].as_str(), Some("None"), "--worker-dns must name a headless Service");
    let (wc, _) = container(get(&objs, "Deployment", "edgepoint-worker"));
    assert_eq!(dns.port, named_port(wc, "grpc"), "--worker-dns port == the workers' gRPC port");
    assert!(!dns.tls, "workers speak plaintext inside the cluster");
    assert!(args.workers.is_empty() && args.workers_file.is_none());

    // Every file a flag names is inside a mounted Secret.
    let mounts: Vec<(String, String)> = list(&c["volumeMounts"], "volumeMounts")
        .iter()
        .map(|m| (s(&m["name"], "mount name").to_string(), s(&m["mountPath"], "mountPath").to_string()))
        .collect();
    let volumes = list(&dep["spec"]["template"]["spec"]["volumes"], "volumes");
    for file in [&args.tls_cert, &args.tls_key, &args.token_file, &args.worker_token_file] {
        let file = file.as_ref().expect("TLS and token files are configured").display().to_string();
        let (vol, _) = mounts.iter().find(|(_, p)| file.starts_with(&format!("{p}/"))).unwrap_or_else(|| panic!("{file} is not under a volumeMount"));
        let v = volumes.iter().find(|v| v["name"].as_str() == Some(vol)).unwrap_or_else(|| panic!("no volume {vol}"));
        assert!(v["secret"]["secretName"].as_str().is_some(), "{file} should come from a Secret");
    }

    let svc = get(&objs, "Service", "edgepoint-server");
    assert!(selects(&labels(&svc["spec"]["selector"]), &pod));
    let p = &list(&svc["spec"]["ports"], "ports")[0];
    assert_eq!(resolve_port(&p["targetPort"], c), grpc);
}

#[test]
fn compose_and_dockerfile_agree_with_the_binaries() {
    let compose = &load(&deploy_dir().join("compose.yaml"))[0];
    let services = &compose["services"];
    let worker = &services["worker"];
    let w_argv = strings(&worker["command"], "worker command");
    let w = WorkerArgs::try_parse_from(&w_argv).unwrap_or_else(|e| panic!("edgepoint-worker rejects {w_argv:?}: {e}"));
    let w_listen: SocketAddr = w.listen.parse().unwrap();
    check_worker_exposure(w_listen, w.tls_cert.is_some(), w.token_file.is_some(), w.insecure).unwrap();
    check_metrics_exposure(w.metrics_listen.as_deref().unwrap().parse().unwrap(), w.metrics_public).unwrap();
    assert!(worker["deploy"]["replicas"].as_i64().unwrap() >= 2, "several workers");
    let exposed = strings(&worker["expose"], "expose");
    assert!(exposed.contains(&w_listen.port().to_string()));

    let server = &services["server"];
    let s_argv = strings(&server["command"], "server command");
    let sv = ServerArgs::try_parse_from(&s_argv).unwrap_or_else(|e| panic!("edgepoint-server rejects {s_argv:?}: {e}"));
    let s_listen: SocketAddr = sv.listen.parse().unwrap();
    check_exposure(s_listen, Protection { tls: sv.tls_cert.is_some(), token: Some(sv.token_file.is_some()), insecure: sv.insecure }).unwrap();
    check_metrics_exposure(sv.metrics_listen.as_deref().unwrap().parse().unwrap(), sv.metrics_public).unwrap();
    // The renderer sends the token the workers accept, both from the compose secret.
    assert_eq!(sv.worker_token_file, w.token_file, "one shared worker token");
    let secret = compose["secrets"]["worker_token"]["file"].as_str().expect("the worker_token secret");
    assert_eq!(w.token_file.as_ref().unwrap().display().to_string(), "/run/secrets/worker_token");
    for svc in [worker, server] {
        assert!(strings(&svc["secrets"], "secrets").iter().any(|s| s == "worker_token"), "{secret} is given to both services");
    }
    // Compose's DNS answers the service name with every replica.
    let dns = WorkerAddr::parse(&sv.worker_dns[0]).unwrap();
    assert_eq!(dns.host, "worker", "--worker-dns names the worker service");
    assert_eq!(dns.port, w_listen.port());
    // Published on the host's loopback only, since it runs --insecure.
    for p in strings(&server["ports"], "ports") {
        assert!(p.starts_with("127.0.0.1:"), "an --insecure renderer must not be published beyond loopback: {p}");
    }
    let published: Vec<u16> = strings(&server["ports"], "ports").iter().map(|p| p.rsplit(':').next().unwrap().parse().unwrap()).collect();
    assert!(published.contains(&s_listen.port()));

    // Compose resolves the build context against the compose file's directory.
    let dockerfile_path = deploy_dir().join(s(&worker["build"]["context"], "context")).join(s(&worker["build"]["dockerfile"], "dockerfile"));
    let dockerfile = std::fs::read_to_string(&dockerfile_path).unwrap_or_else(|e| panic!("{}: {e}", dockerfile_path.display()));
    assert_eq!(dockerfile_path.canonicalize().unwrap(), deploy_dir().join("Dockerfile").canonicalize().unwrap());
    for bin in [edgepoint_viewer::local::SERVER_BIN, edgepoint_viewer::local::WORKER_BIN, "edgepoint-viewer"] {
        assert!(dockerfile.contains(&format!("-p {bin}")), "the image builds {bin}");
        assert!(dockerfile.contains(&format!("target/release/{bin}")), "the image ships {bin}");
    }
    assert!(dockerfile.contains("--locked"), "the image builds the locked dependency versions");
    assert!(!dockerfile.contains("protobuf-compiler") && !dockerfile.contains("apt-get install -y protoc"), "no protoc: protox compiles the contract");
    assert!(dockerfile.contains("USER 10001"));
    let k = k8s();
    for dep in ["edgepoint-worker", "edgepoint-server"] {
        let (c, _) = container(get(&k, "Deployment", dep));
        let uid = get(&k, "Deployment", dep)["spec"]["template"]["spec"]["securityContext"]["runAsUser"].as_i64();
        assert_eq!(uid, Some(10001), "{dep} runs as the image's user");
        for name in ["grpc", "metrics"] {
            let port = named_port(c, name);
            assert!(dockerfile.contains(&port.to_string()), "EXPOSE lists {dep}'s {name} port {port}");
        }
    }
    let ignore = std::fs::read_to_string(deploy_dir().join("../.dockerignore")).expect(".dockerignore at the build context");
    assert!(ignore.lines().any(|l| l.trim() == "target/"), "the build context leaves target/ out");
}
