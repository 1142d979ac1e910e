//! TCP listen/accept: owned by the server work (issue 3).
