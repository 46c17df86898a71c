//! Scene loading errors: always name the file, the place in it and the reason.
use std::fmt;

/// Where in a file an error is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Location {
    /// Whole file (e.g. unknown extension, empty).
    File,
    /// 1-based text line.
    Line(usize),
    /// A PLY element record, e.g. `face 1234` (0-based index within the element).
    Element(String, usize),
    /// Byte offset in a binary file.
    Byte(u64),
}

/// A scene could not be loaded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub struct SceneError {
    pub file: String,
    pub location: Location,
    pub reason: String,
}

impl SceneError {
    pub fn new(file: impl Into<String>, location: Location, reason: impl Into<String>) -> Self {
        SceneError { file: file.into(), location, reason: reason.into() }
    }
    pub fn file(file: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::new(file, Location::File, reason)
    }
    pub fn line(file: impl Into<String>, line: usize, reason: impl Into<String>) -> Self {
        Self::new(file, Location::Line(line), reason)
    }
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.location {
            Location::File => write!(f, "{}: {}", self.file, self.reason),
            Location::Line(l) => write!(f, "{}:{}: {}", self.file, l, self.reason),
            Location::Element(e, i) => write!(f, "{}: {} {}: {}", self.file, e, i, self.reason),
            Location::Byte(b) => write!(f, "{}: byte {}: {}", self.file, b, self.reason),
        }
    }
}
