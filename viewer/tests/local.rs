//! `LocalCluster` with fake worker/server executables: wiring, kill/restart, failures that
//! name the binary and quote its stderr, and children reaped on drop.
mod common;

use common::*;
use edgepoint_viewer::local::{find_binary, find_binary_in, LocalCluster, LocalOptions};
use std::net::SocketAddr;
use std::path::Path;
use std::time::Duration;

fn opts(bin_dir: &Path, workers: usize) -> LocalOptions {
    LocalOptions { workers, bin_dir: Some(bin_dir.to_path_buf()), log_level: Some("warn".into()), ..LocalOptions::default() }
}

fn fake_server_addr() -> SocketAddr {
    "127.0.0.1:45999".parse().unwrap()
}

#[test]
fn starts_workers_then_a_server_pointed_at_them() {
    let dir = tempfile::tempdir().unwrap();
    fake_bin_dir(dir.path(), fake_server_addr());
    let o = LocalOptions { worker_threads: Some(3), server_args: vec!["--x".into()], ..opts(dir.path(), 2) };
    let c = LocalCluster::start(o).unwrap();
    assert_eq!(c.server_addr(), fake_server_addr());
    assert_eq!(c.server_url(), "http://127.0.0.1:45999");
    let workers = fake_log(dir.path(), "edgepoint-worker");
    let addrs = c.worker_addrs();
    assert_eq!(addrs.len(), 2);
    // Each worker's address is what that process printed (the fake derives it from its pid).
    for (i, a) in addrs.iter().enumerate() {
        let pid = c.pid(i).unwrap() as i32;
        assert!(workers.iter().any(|(p, args)| *p == pid && args == "--listen 127.0.0.1:0 --threads 3"));
        assert_eq!(a.port() as i32, 20000 + pid % 20000);
    }
    let server = fake_log(dir.path(), "edgepoint-server");
    assert_eq!(server[0].1, format!("--listen 127.0.0.1:0 --worker http://{} --worker http://{} --x", addrs[0], addrs[1]));
    assert_eq!(c.server_pid(), Some(server[0].0 as u32));
}

#[test]
fn kill_and_restart_keep_the_worker_address() {
    let dir = tempfile::tempdir().unwrap();
    fake_bin_dir(dir.path(), fake_server_addr());
    let mut c = LocalCluster::start(opts(dir.path(), 2)).unwrap();
    let addr = c.worker_addrs()[1];
    let old = c.pid(1).unwrap() as i32;
    assert!(c.worker_alive(1));
    c.kill_worker(1).unwrap();
    assert!(!alive(old), "SIGKILLed and reaped");
    assert_eq!(c.pid(1), None);
    assert!(!c.worker_alive(1));
    c.kill_worker(1).unwrap(); // idempotent
    assert!(c.kill_worker(5).unwrap_err().to_string().contains("no worker 5"));

    c.restart_worker(1).unwrap();
    let new = c.pid(1).unwrap() as i32;
    assert_ne!(new, old);
    assert_eq!(c.worker_addrs()[1], addr);
    let log = fake_log(dir.path(), "edgepoint-worker");
    assert!(log.iter().any(|(p, args)| *p == new && *args == format!("--listen {addr}")), "{log:?}");

    // Restarting a live worker replaces it.
    c.restart_worker(0).unwrap();
    assert!(c.worker_alive(0));
}

#[test]
fn dropping_the_cluster_kills_every_child() {
    let dir = tempfile::tempdir().unwrap();
    fake_bin_dir(dir.path(), fake_server_addr());
    let c = LocalCluster::start(opts(dir.path(), 3)).unwrap();
    let pids: Vec<i32> = (0..3).map(|i| c.pid(i).unwrap() as i32).chain([c.server_pid().unwrap() as i32]).collect();
    assert!(pids.iter().all(|&p| alive(p)));
    drop(c);
    for p in pids {
        assert!(!alive(p), "child {p} outlived the cluster");
    }
}

#[test]
fn a_worker_that_dies_is_named_with_its_stderr() {
    let dir = tempfile::tempdir().unwrap();
    fake_bin_dir(dir.path(), fake_server_addr());
    write_script(&dir.path().join("edgepoint-worker"), "echo 'error: cannot bind 127.0.0.1:0: boom' >&2\nexit 3\n");
    let err = format!("{:#}", LocalCluster::start(opts(dir.path(), 2)).unwrap_err());
    assert!(err.contains("edgepoint-worker #0"), "{err}");
    assert!(err.contains("exited") && err.contains("cannot bind 127.0.0.1:0: boom"), "{err}");
    assert!(fake_log(dir.path(), "edgepoint-server").is_empty(), "no server without workers");
}

#[test]
fn a_silent_server_times_out_and_workers_are_cleaned_up() {
    let dir = tempfile::tempdir().unwrap();
    fake_bin_dir(dir.path(), fake_server_addr());
    write_script(
        &dir.path().join("edgepoint-server"),
        &format!("echo \"$$\" >> '{}'\necho 'loading...' >&2\nexec sleep 600\n", dir.path().join("silent.pid").display()),
    );
    let o = LocalOptions { startup_timeout: Duration::from_millis(700), ..opts(dir.path(), 1) };
    let err = format!("{:#}", LocalCluster::start(o).unwrap_err());
    assert!(err.contains("edgepoint-server") && err.contains("did not print `listening <addr>`"), "{err}");
    assert!(err.contains("loading..."), "quotes its stderr: {err}");
    let server: i32 = std::fs::read_to_string(dir.path().join("silent.pid")).unwrap().trim().parse().unwrap();
    assert!(!alive(server), "the silent server was killed");
    for (pid, _) in fake_log(dir.path(), "edgepoint-worker") {
        assert!(!alive(pid), "worker {pid} outlived the failed start");
    }
}

#[test]
fn a_garbled_listening_line_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    fake_bin_dir(dir.path(), fake_server_addr());
    write_script(&dir.path().join("edgepoint-worker"), "echo 'listening somewhere'\nexec sleep 600\n");
    let err = format!("{:#}", LocalCluster::start(opts(dir.path(), 1)).unwrap_err());
    assert!(err.contains("`listening somewhere`") && err.contains("not a socket address"), "{err}");
}

#[test]
fn zero_workers_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    fake_bin_dir(dir.path(), fake_server_addr());
    assert!(LocalCluster::start(opts(dir.path(), 0)).unwrap_err().to_string().contains("at least one worker"));
}

#[test]
fn find_binary_searches_the_given_dir_first_and_explains_failure() {
    let dir = tempfile::tempdir().unwrap();
    fake_bin_dir(dir.path(), fake_server_addr());
    assert_eq!(find_binary_in("edgepoint-worker", Some(dir.path())).unwrap(), dir.path().join("edgepoint-worker"));
    // Not executable: skipped.
    std::fs::write(dir.path().join("edgepoint-plain"), "data").unwrap();
    let err = find_binary_in("edgepoint-plain", Some(dir.path())).unwrap_err().to_string();
    assert!(err.contains("edgepoint-plain") && err.contains(&dir.path().display().to_string()), "{err}");
    assert!(err.contains("PATH") && err.contains("cargo build --release") && err.contains("EDGEPOINT_BIN_DIR"), "{err}");
    // The test executable's directory and its parent are searched too.
    let exe_dir = std::env::current_exe().unwrap().parent().unwrap().to_path_buf();
    let err = find_binary("edgepoint-no-such-binary").unwrap_err().to_string();
    assert!(err.contains(&exe_dir.display().to_string()) && err.contains(&exe_dir.parent().unwrap().display().to_string()), "{err}");
}

#[test]
fn a_log_file_collects_the_childrens_stderr() {
    let dir = tempfile::tempdir().unwrap();
    fake_bin_dir(dir.path(), fake_server_addr());
    let log = dir.path().join("cluster.log");
    let c = LocalCluster::start(LocalOptions { log_file: Some(log.clone()), ..opts(dir.path(), 2) }).unwrap();
    let addrs = c.worker_addrs();
    assert!(eventually(5, || {
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        (0..2).all(|i| text.contains(&format!("[edgepoint-worker #{i}] worker starting on {}", addrs[i])))
    }));
}

/// Niceness of a process (field 19 of /proc/PID/stat).
#[cfg(target_os = "linux")]
fn niceness(pid: u32) -> i32 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap();
    // The command name (field 2) is in parentheses and may hold spaces: count after it.
    let after = &stat[stat.rfind(')').unwrap() + 2..];
    after.split(' ').nth(16).unwrap().parse().unwrap()
}

/// Linux's `SCHED_IDLE` policy number (`/proc/PID/stat` field 41).
#[cfg(target_os = "linux")]
const SCHED_IDLE: i64 = 5;

/// A process's scheduling policy, from `/proc/PID/stat` (field 41).
#[cfg(target_os = "linux")]
fn policy(pid: u32) -> i64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap();
    let after = &stat[stat.rfind(')').unwrap() + 2..];
    after.split(' ').nth(38).unwrap().parse().unwrap()
}

#[cfg(target_os = "linux")]
#[test]
fn workers_run_below_the_server_priority() {
    let dir = tempfile::tempdir().unwrap();
    fake_bin_dir(dir.path(), fake_server_addr());
    let me = niceness(std::process::id());
    let my_policy = policy(std::process::id());
    let c = LocalCluster::start(LocalOptions { worker_nice: 3, ..opts(dir.path(), 2) }).unwrap();
    for i in 0..2 {
        assert_eq!(niceness(c.pid(i).unwrap()), (me + 3).min(19), "worker {i}");
        assert_eq!(policy(c.pid(i).unwrap()), SCHED_IDLE, "worker {i} runs under SCHED_IDLE by default");
    }
    assert_eq!(niceness(c.server_pid().unwrap()), me, "the server keeps this process's priority");
    assert_eq!(policy(c.server_pid().unwrap()), my_policy, "and its scheduling policy");
    drop(c);
    let c = LocalCluster::start(LocalOptions { worker_nice: 0, worker_idle: false, ..opts(dir.path(), 1) }).unwrap();
    assert_eq!(niceness(c.pid(0).unwrap()), me);
    assert_eq!(policy(c.pid(0).unwrap()), my_policy);
}
