//! Server exports: owned by the server work (issue 3).
