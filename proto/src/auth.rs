//! Bearer tokens: the token file format shared by the server (`--token-file`: the viewer
//! tokens it accepts; `--worker-token-file`: the one it sends its workers), the worker
//! (`--token-file`: the renderer tokens it accepts) and the viewer (`--token-file`: the one it
//! sends), the `authorization` metadata, the check of a call's token against the accepted
//! ones (with a comparison that does not leak where a guess differs), and the interceptors
//! that add and check it on every gRPC call.
use std::path::Path;
use std::sync::Arc;
use tonic::metadata::{Ascii, MetadataMap, MetadataValue};
use tonic::Status;

/// The gRPC metadata key carrying `Bearer <token>`.
pub const AUTHORIZATION: &str = "authorization";

/// Reads tokens from `path`: one per line, surrounding whitespace ignored, blank lines and
/// `#` comments skipped (several lines let a server accept an old and a new token while
/// they are rotated). A token must be printable ASCII without spaces, so it fits in a header.
pub fn read_token_file(path: &Path) -> Result<Vec<String>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("cannot read the token file {}: {e}", path.display()))?;
    let mut tokens = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        check_token(t).map_err(|e| format!("{}: line {}: {e}", path.display(), i + 1))?;
        tokens.push(t.to_string());
    }
    if tokens.is_empty() {
        return Err(format!("the token file {} holds no token", path.display()));
    }
    Ok(tokens)
}

/// A token must be 16..=4096 printable ASCII characters without spaces.
pub fn check_token(t: &str) -> Result<(), String> {
    if t.len() < 16 {
        return Err(format!("a token needs at least 16 characters, this one has {}", t.len()));
    }
    if t.len() > 4096 {
        return Err("a token may have at most 4096 characters".into());
    }
    if !t.bytes().all(|b| b.is_ascii_graphic()) {
        return Err("a token may hold only printable ASCII characters without spaces".into());
    }
    Ok(())
}

/// The metadata value for `token`.
pub fn bearer(token: &str) -> String {
    format!("Bearer {token}")
}

/// The token of an `authorization` value (`Bearer <token>`, scheme case-insensitive).
pub fn parse_bearer(value: &str) -> Option<&str> {
    let (scheme, token) = value.trim().split_once(' ')?;
    scheme.eq_ignore_ascii_case("bearer").then(|| token.trim()).filter(|t| !t.is_empty())
}

/// Checks the bearer token in `md` against `accepted`. `hint` tells a caller without a token
/// how to send one (e.g. which flag of which program).
pub fn check_bearer(md: &MetadataMap, accepted: &[String], hint: &str) -> Result<(), Status> {
    let Some(value) = md.get(AUTHORIZATION) else {
        return Err(Status::unauthenticated(format!("this service requires a bearer token: {hint}")));
    };
    let value = value.to_str().map_err(|_| Status::unauthenticated("the authorization header is not ASCII"))?;
    let token = parse_bearer(value).ok_or_else(|| Status::unauthenticated("the authorization header must be `Bearer <token>`"))?;
    // Compare against every accepted token, so the time taken does not tell which matched.
    let ok = accepted.iter().fold(false, |ok, t| ok | constant_time_eq(t, token));
    if ok {
        Ok(())
    } else {
        Err(Status::unauthenticated("invalid bearer token"))
    }
}

/// Adds `authorization: Bearer <token>` to every call (`None`: adds nothing). The
/// renderer's calls to its workers go through it.
#[derive(Clone, Default)]
pub struct SendToken(Option<MetadataValue<Ascii>>);

impl SendToken {
    pub fn new(token: Option<&str>) -> Result<SendToken, String> {
        match token {
            None => Ok(SendToken(None)),
            Some(t) => {
                check_token(t)?;
                let v = bearer(t).parse().map_err(|_| "the token is not a valid header value".to_string())?;
                Ok(SendToken(Some(v)))
            }
        }
    }
}

impl std::fmt::Debug for SendToken {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() { "SendToken(<token>)" } else { "SendToken(none)" })
    }
}

impl tonic::service::Interceptor for SendToken {
    fn call(&mut self, mut req: tonic::Request<()>) -> Result<tonic::Request<()>, Status> {
        if let Some(v) = &self.0 {
            req.metadata_mut().insert(AUTHORIZATION, v.clone());
        }
        Ok(req)
    }
}

/// Refuses every call without one of the accepted tokens with UNAUTHENTICATED (`None`:
/// accepts every call). A worker's service goes behind it.
#[derive(Clone)]
pub struct RequireToken {
    accepted: Option<Arc<Vec<String>>>,
    hint: &'static str,
}

impl RequireToken {
    pub fn new(accepted: Option<Arc<Vec<String>>>, hint: &'static str) -> Self {
        RequireToken { accepted, hint }
    }
}

impl tonic::service::Interceptor for RequireToken {
    fn call(&mut self, req: tonic::Request<()>) -> Result<tonic::Request<()>, Status> {
        if let Some(a) = &self.accepted {
            check_bearer(req.metadata(), a, self.hint)?;
        }
        Ok(req)
    }
}

/// Equal strings, compared in time that depends only on their lengths.
pub fn constant_time_eq(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    let mut diff = (a.len() ^ b.len()) as u64;
    for i in 0..a.len().max(b.len()) {
        let x = a.get(i).copied().unwrap_or(0);
        let y = b.get(i).copied().unwrap_or(0);
        diff |= (x ^ y) as u64;
    }
    diff == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn token_files_parse_and_name_bad_lines() {
        let dir = std::env::temp_dir().join(format!("edgepoint-auth-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("tokens");
        std::fs::write(&p, "# rotation\n  0123456789abcdef0123  \n\nnew-token-000000000000\n").unwrap();
        assert_eq!(read_token_file(&p).unwrap(), vec!["0123456789abcdef0123", "new-token-000000000000"]);
        std::fs::write(&p, "0123456789abcdef0123\nshort\n").unwrap();
        let e = read_token_file(&p).unwrap_err();
        assert!(e.contains("line 2") && e.contains("16"), "{e}");
        std::fs::write(&p, "# nothing\n").unwrap();
        assert!(read_token_file(&p).unwrap_err().contains("no token"));
        assert!(read_token_file(&dir.join("absent")).unwrap_err().contains("absent"));
        assert!(check_token("has a space in it ok").is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn interceptors_send_and_require_tokens() {
        use tonic::service::Interceptor;
        let token = "renderer-token-0123456789";
        let mut send = SendToken::new(Some(token)).unwrap();
        let req = send.call(tonic::Request::new(())).unwrap();
        let mut require = RequireToken::new(Some(Arc::new(vec!["old-token-000000000000".into(), token.into()])), "start the renderer with --worker-token-file");
        assert!(require.call(req).is_ok());
        let e = require.call(tonic::Request::new(())).unwrap_err();
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        assert!(e.message().contains("--worker-token-file"), "{}", e.message());
        let wrong = SendToken::new(Some("wrong-token-0123456789")).unwrap().call(tonic::Request::new(())).unwrap();
        assert!(require.call(wrong).unwrap_err().message().contains("invalid"));
        assert!(RequireToken::new(None, "").call(tonic::Request::new(())).is_ok(), "no tokens configured: open");
        assert!(SendToken::new(Some("short")).is_err());
    }

    #[test]
    fn bearer_values_round_trip_and_compare() {
        assert_eq!(parse_bearer(&bearer("abc")), Some("abc"));
        assert_eq!(parse_bearer("bearer  xyz "), Some("xyz"));
        assert_eq!(parse_bearer("Basic abc"), None);
        assert_eq!(parse_bearer("Bearer"), None);
        assert!(constant_time_eq("same-token", "same-token"));
        assert!(!constant_time_eq("same-token", "same-tokem"));
        assert!(!constant_time_eq("same", "same-token"));
        assert!(!constant_time_eq("", "x"));
    }
}
