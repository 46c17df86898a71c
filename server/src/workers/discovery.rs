//! Where the shader workers are (DESIGN.md "deploy": workers run as a Deployment behind a
//! headless Service; the renderer resolves every worker address from DNS and follows
//! scale-up and scale-down).
//!
//! Three kinds of source, combined into one sorted set of members:
//! - fixed addresses (`--worker URL`);
//! - DNS names re-resolved every interval (`--worker-dns HOST:PORT`): every A/AAAA record is
//!   one worker. This is the Kubernetes headless-Service pattern (one record per ready pod)
//!   and also how Docker Compose answers for a service with replicas;
//! - a file re-read every interval (`--workers-file FILE`): one address per line, `#`
//!   comments. Replace it atomically (write a new file, rename it over the old one).
//!
//! A source that fails to answer (a DNS timeout, an unreadable file) keeps its previous
//! workers — a DNS hiccup must not empty the pool — until it has failed for
//! [`DNS_GRACE`], after which a name that no longer resolves counts as having no workers.
use super::PoolError;
use std::collections::BTreeMap;
use std::future::Future;
use std::net::IpAddr;
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How long a DNS name may keep failing before its workers are dropped.
pub const DNS_GRACE: Duration = Duration::from_secs(30);
/// Deadline of one DNS lookup.
pub const LOOKUP_TIMEOUT: Duration = Duration::from_secs(5);
/// Default re-resolution interval.
pub const DEFAULT_INTERVAL: Duration = Duration::from_secs(1);

/// Where to find workers.
#[derive(Debug, Clone)]
pub struct WorkerSources {
    /// Fixed worker addresses: `http://host:port`, `https://host:port` or `host:port`.
    pub urls: Vec<String>,
    /// DNS names whose A/AAAA records are the workers: `[http[s]://]host:port`.
    pub dns: Vec<String>,
    /// A file of worker addresses, one per line.
    pub file: Option<PathBuf>,
    /// How often DNS names and the file are read again.
    pub interval: Duration,
}

impl Default for WorkerSources {
    fn default() -> Self {
        WorkerSources { urls: Vec::new(), dns: Vec::new(), file: None, interval: DEFAULT_INTERVAL }
    }
}

impl WorkerSources {
    /// Fixed addresses only.
    pub fn fixed(urls: Vec<String>) -> Self {
        WorkerSources { urls, ..Default::default() }
    }

    /// Sources that change over time (DNS or a file) need a discovery task.
    pub fn is_dynamic(&self) -> bool {
        !self.dns.is_empty() || self.file.is_some()
    }
}

/// A worker address, split and checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WorkerAddr {
    pub tls: bool,
    pub host: String,
    pub port: u16,
}

impl WorkerAddr {
    /// Parses `http://host:port`, `https://host:port` or `host:port` (plain HTTP/2); an IPv6
    /// host goes in brackets. Nothing may follow the port but a `/`.
    pub fn parse(s: &str) -> Result<WorkerAddr, String> {
        let s = s.trim();
        let (tls, rest) = if let Some(r) = s.strip_prefix("https://") {
            (true, r)
        } else if let Some(r) = s.strip_prefix("http://") {
            (false, r)
        } else if s.contains("://") {
            return Err("the scheme must be http:// or https://".into());
        } else {
            (false, s)
        };
        let rest = rest.strip_suffix('/').unwrap_or(rest);
        if rest.contains('/') || rest.contains('?') || rest.contains('@') {
            return Err("expected host:port with no path".into());
        }
        let (host, port) = if let Some(v6) = rest.strip_prefix('[') {
            let (h, p) = v6.split_once("]:").ok_or("an IPv6 address needs the form [addr]:port")?;
            h.parse::<std::net::Ipv6Addr>().map_err(|_| format!("'{h}' is not an IPv6 address"))?;
            (h.to_string(), p)
        } else {
            let (h, p) = rest.rsplit_once(':').ok_or("missing :port")?;
            (h.to_string(), p)
        };
        if host.is_empty() {
            return Err("missing host".into());
        }
        if !host.contains(':') && !host.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '.' || c == '_') {
            return Err(format!("'{host}' is not a host name or address"));
        }
        let port: u16 = port.parse().map_err(|_| format!("'{port}' is not a port number"))?;
        if port == 0 {
            return Err("port 0 is not a worker's port".into());
        }
        Ok(WorkerAddr { tls, host, port })
    }

    fn scheme(&self) -> &'static str {
        if self.tls {
            "https"
        } else {
            "http"
        }
    }

    /// `scheme://host:port`.
    pub fn url(&self) -> String {
        url_of(self.scheme(), &self.host, self.port)
    }
}

fn url_of(scheme: &str, host: &str, port: u16) -> String {
    if host.contains(':') {
        format!("{scheme}://[{host}]:{port}")
    } else {
        format!("{scheme}://{host}:{port}")
    }
}

/// One worker as the pool sees it.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct Member {
    /// `http[s]://host:port`: the identity of the worker in the pool and in metrics.
    pub url: String,
    /// For a TLS worker found through DNS: the name its certificate must carry (the DNS
    /// name, since the URL holds a bare IP address).
    pub tls_domain: Option<String>,
}

impl Member {
    fn of(addr: &WorkerAddr) -> Member {
        Member { url: addr.url(), tls_domain: None }
    }
}

/// Resolves host names. The system resolver in production; tests substitute their own.
pub trait Resolve: Send + Sync + 'static {
    fn lookup<'a>(&'a self, host: &'a str, port: u16) -> Pin<Box<dyn Future<Output = std::io::Result<Vec<IpAddr>>> + Send + 'a>>;
}

/// The operating system's resolver (getaddrinfo on a blocking thread, via tokio).
pub struct SystemResolver;

impl Resolve for SystemResolver {
    fn lookup<'a>(&'a self, host: &'a str, port: u16) -> Pin<Box<dyn Future<Output = std::io::Result<Vec<IpAddr>>> + Send + 'a>> {
        Box::pin(async move { Ok(tokio::net::lookup_host((host, port)).await?.map(|a| a.ip()).collect()) })
    }
}

struct DnsSource {
    addr: WorkerAddr,
    last: Vec<Member>,
    failing_since: Option<Instant>,
}

/// The state of discovery between polls.
pub struct Discovery {
    fixed: Vec<Member>,
    dns: Vec<DnsSource>,
    file: Option<(PathBuf, Vec<Member>)>,
    resolver: Arc<dyn Resolve>,
}

impl Discovery {
    /// Checks every address of `sources` (a bad one is an error naming it).
    pub fn new(sources: &WorkerSources, resolver: Arc<dyn Resolve>) -> Result<Discovery, PoolError> {
        let bad = |addr: &str, reason: String| PoolError::BadAddress { addr: addr.to_string(), reason };
        let mut fixed = Vec::new();
        for u in &sources.urls {
            fixed.push(Member::of(&WorkerAddr::parse(u).map_err(|r| bad(u, r))?));
        }
        let mut dns = Vec::new();
        for d in &sources.dns {
            let addr = WorkerAddr::parse(d).map_err(|r| bad(d, r))?;
            dns.push(DnsSource { addr, last: Vec::new(), failing_since: None });
        }
        let file = sources.file.clone().map(|p| (p, Vec::new()));
        Ok(Discovery { fixed, dns, file, resolver })
    }

    /// Reads every source again and returns the current members, sorted, without repeats.
    pub async fn poll(&mut self) -> Vec<Member> {
        let mut all: BTreeMap<String, Member> = BTreeMap::new();
        for m in &self.fixed {
            all.insert(m.url.clone(), m.clone());
        }
        for src in &mut self.dns {
            let a = &src.addr;
            match tokio::time::timeout(LOOKUP_TIMEOUT, self.resolver.lookup(&a.host, a.port)).await {
                Ok(Ok(ips)) => {
                    let mut members: Vec<Member> = ips
                        .iter()
                        .map(|ip| Member {
                            url: url_of(a.scheme(), &ip.to_string(), a.port),
                            tls_domain: a.tls.then(|| a.host.clone()),
                        })
                        .collect();
                    members.sort();
                    members.dedup();
                    if src.failing_since.take().is_some() {
                        tracing::info!(name = %a.host, workers = members.len(), "worker DNS name resolves again");
                    }
                    src.last = members;
                }
                failed => {
                    let why = match failed {
                        Ok(Err(e)) => e.to_string(),
                        _ => format!("no answer within {LOOKUP_TIMEOUT:?}"),
                    };
                    let since = *src.failing_since.get_or_insert_with(|| {
                        tracing::warn!(name = %a.host, "cannot resolve the worker DNS name ({why}); keeping its {} workers for now", src.last.len());
                        Instant::now()
                    });
                    if since.elapsed() > DNS_GRACE && !src.last.is_empty() {
                        tracing::warn!(name = %a.host, "the worker DNS name failed for {DNS_GRACE:?}; dropping its workers");
                        src.last.clear();
                    }
                }
            }
            for m in &src.last {
                all.insert(m.url.clone(), m.clone());
            }
        }
        if let Some((path, last)) = &mut self.file {
            match read_workers_file(path) {
                Ok(members) => *last = members,
                Err(e) => tracing::warn!("{e}; keeping the {} workers it listed before", last.len()),
            }
            for m in last.iter() {
                all.insert(m.url.clone(), m.clone());
            }
        }
        all.into_values().collect()
    }
}

/// Parses a workers file. A bad line is skipped with a warning naming the file and line;
/// only an unreadable file is an error.
pub fn read_workers_file(path: &Path) -> Result<Vec<Member>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("cannot read the workers file {}: {e}", path.display()))?;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        match WorkerAddr::parse(line) {
            Ok(a) => out.push(Member::of(&a)),
            Err(e) => tracing::warn!("{}: line {}: '{line}' ignored: {e}", path.display(), i + 1),
        }
    }
    out.sort();
    out.dedup();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;
    use std::sync::Mutex;

    #[test]
    fn addresses_parse_with_or_without_scheme() {
        let a = WorkerAddr::parse("worker.ns.svc:50061").unwrap();
        assert_eq!((a.tls, a.host.as_str(), a.port), (false, "worker.ns.svc", 50061));
        assert_eq!(a.url(), "http://worker.ns.svc:50061");
        assert_eq!(WorkerAddr::parse("https://w:1/").unwrap().url(), "https://w:1");
        assert_eq!(WorkerAddr::parse("[::1]:7").unwrap().url(), "http://[::1]:7");
        for (bad, why) in [
            ("w", "port"),
            ("w:0", "port 0"),
            ("w:x", "'x'"),
            (":5", "host"),
            ("grpc://w:5", "scheme"),
            ("http://w:5/path", "path"),
            ("[::1:5", "[addr]:port"),
            ("wo rker:5", "host name"),
        ] {
            let e = WorkerAddr::parse(bad).unwrap_err();
            assert!(e.contains(why), "{bad}: {e}");
        }
    }

    /// A resolver answering from a table that the test edits; a missing name fails.
    #[derive(Default)]
    struct Table(Mutex<HashMap<String, Vec<IpAddr>>>);
    impl Resolve for Table {
        fn lookup<'a>(&'a self, host: &'a str, _port: u16) -> Pin<Box<dyn Future<Output = std::io::Result<Vec<IpAddr>>> + Send + 'a>> {
            let r = self.0.lock().unwrap().get(host).cloned();
            Box::pin(async move { r.ok_or_else(|| std::io::Error::other("no such name")) })
        }
    }

    fn urls(m: &[Member]) -> Vec<&str> {
        m.iter().map(|m| m.url.as_str()).collect()
    }

    #[tokio::test]
    async fn dns_names_follow_their_records_and_survive_failures() {
        let table = Arc::new(Table::default());
        let ip = |s: &str| s.parse::<IpAddr>().unwrap();
        table.0.lock().unwrap().insert("workers".into(), vec![ip("10.0.0.2"), ip("10.0.0.1"), ip("10.0.0.2")]);
        let sources = WorkerSources {
            urls: vec!["static:9".into()],
            dns: vec!["workers:50061".into(), "https://secure:7".into()],
            ..Default::default()
        };
        let mut d = Discovery::new(&sources, table.clone()).unwrap();
        let m = d.poll().await;
        assert_eq!(urls(&m), ["http://10.0.0.1:50061", "http://10.0.0.2:50061", "http://static:9"], "sorted, deduplicated");
        // Scale up, and a TLS name appears: its members carry the name for certificate checks.
        table.0.lock().unwrap().insert("workers".into(), vec![ip("10.0.0.1"), ip("10.0.0.2"), ip("fd00::3")]);
        table.0.lock().unwrap().insert("secure".into(), vec![ip("10.1.0.1")]);
        let m = d.poll().await;
        assert_eq!(urls(&m), ["http://10.0.0.1:50061", "http://10.0.0.2:50061", "http://[fd00::3]:50061", "http://static:9", "https://10.1.0.1:7"]);
        assert_eq!(m[4].tls_domain.as_deref(), Some("secure"));
        assert_eq!(m[0].tls_domain, None);
        // A failing lookup keeps the previous answer (within the grace period).
        table.0.lock().unwrap().remove("workers");
        assert_eq!(d.poll().await.len(), 5);
        // Scale down.
        table.0.lock().unwrap().insert("workers".into(), vec![ip("10.0.0.2")]);
        assert_eq!(urls(&d.poll().await), ["http://10.0.0.2:50061", "http://static:9", "https://10.1.0.1:7"]);
        assert!(Discovery::new(&WorkerSources { dns: vec!["nope".into()], ..Default::default() }, table).is_err());
    }

    #[tokio::test]
    async fn the_workers_file_is_reread_and_bad_lines_skipped() {
        let dir = std::env::temp_dir().join(format!("edgepoint-discovery-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("workers.txt");
        std::fs::write(&path, "# pool\n127.0.0.1:1\nhttp://127.0.0.1:2  # second\n\nbad line\n").unwrap();
        let sources = WorkerSources { file: Some(path.clone()), ..Default::default() };
        let mut d = Discovery::new(&sources, Arc::new(SystemResolver)).unwrap();
        assert_eq!(urls(&d.poll().await), ["http://127.0.0.1:1", "http://127.0.0.1:2"]);
        std::fs::write(&path, "127.0.0.1:2\n127.0.0.1:3\n").unwrap();
        assert_eq!(urls(&d.poll().await), ["http://127.0.0.1:2", "http://127.0.0.1:3"]);
        std::fs::remove_file(&path).unwrap();
        assert_eq!(d.poll().await.len(), 2, "an unreadable file keeps the last list");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[tokio::test]
    async fn localhost_resolves_through_the_system() {
        let sources = WorkerSources { dns: vec!["localhost:50061".into()], ..Default::default() };
        let mut d = Discovery::new(&sources, Arc::new(SystemResolver)).unwrap();
        let m = d.poll().await;
        assert!(m.iter().any(|m| m.url == "http://127.0.0.1:50061" || m.url == "http://[::1]:50061"), "{m:?}");
    }
}
