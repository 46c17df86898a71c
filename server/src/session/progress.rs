//! Progress of a session's long work, for its viewer as well as the log (the edge trees of
//! a big mesh take seconds): a [`Progress`] sink that logs like
//! [`crate::reference::LogProgress`] and offers the viewer a `Progress` message per stage,
//! latest-wins, at most every [`SEND_EVERY`].
use super::output::SessionOutput;
use crate::reference::LogProgress;
use edgepoint_proto as pb;
use edgepoint_scene::Progress;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Shortest interval between two progress messages of one stage (the first and the last of
/// a stage always go).
pub const SEND_EVERY: Duration = Duration::from_millis(100);

pub struct ViewerProgress {
    out: Arc<SessionOutput>,
    /// The stage name the viewer sees ("edge trees").
    stage: String,
    log: LogProgress,
    state: Mutex<State>,
}

struct State {
    step: String,
    total: u64,
    done: u64,
    last_sent: Option<Instant>,
}

impl ViewerProgress {
    /// Reports under `stage` to the viewer of `out`; logs with `log_label`.
    pub fn new(out: Arc<SessionOutput>, stage: &str, log_label: &str) -> Self {
        ViewerProgress {
            out,
            stage: stage.to_string(),
            log: LogProgress::new(log_label),
            state: Mutex::new(State { step: String::new(), total: 0, done: 0, last_sent: None }),
        }
    }

    fn send(&self, s: &mut State, force: bool) {
        let now = Instant::now();
        if !force && s.last_sent.is_some_and(|t| now.duration_since(t) < SEND_EVERY) {
            return;
        }
        s.last_sent = Some(now);
        self.out.progress(pb::Progress { stage: self.stage.clone(), done: s.done, total: s.total, message: s.step.clone() });
    }
}

impl Progress for ViewerProgress {
    fn begin(&self, step: &str, total: u64) {
        self.log.begin(step, total);
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        *s = State { step: step.to_string(), total, done: 0, last_sent: None };
        self.send(&mut s, true);
    }

    fn advance(&self, units: u64) {
        self.log.advance(units);
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        s.done = s.done.saturating_add(units);
        self.send(&mut s, false);
    }

    fn end(&self) {
        self.log.end();
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        s.done = s.total.max(s.done);
        s.total = s.done;
        s.step = format!("{} done", s.step);
        self.send(&mut s, true);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use edgepoint_proto::server_msg::Msg;

    #[test]
    fn stages_reach_the_viewer_first_latest_and_done() {
        let out = Arc::new(SessionOutput::new());
        let p = ViewerProgress::new(out.clone(), "edge trees", "test");
        p.begin("building", 100);
        for _ in 0..50 {
            p.advance(1);
        }
        let first = out.try_next().unwrap();
        match first.msg {
            Some(Msg::Progress(q)) => {
                assert_eq!((q.stage.as_str(), q.total, q.message.as_str()), ("edge trees", 100, "building"));
                assert!(q.done <= 50);
            }
            other => panic!("{other:?}"),
        }
        p.advance(50);
        p.end();
        match out.try_next().unwrap().msg {
            Some(Msg::Progress(q)) => assert_eq!((q.done, q.total, q.message.as_str()), (100, 100, "building done")),
            other => panic!("{other:?}"),
        }
        assert!(out.try_next().is_none());
    }
}
