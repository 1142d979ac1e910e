//! Privileges and limits: the `user` option (after the fronts are bound, the lines,
//! the log and the TLS files opened: initgroups, setgid, setuid, so that the user's
//! groups such as `dialout` stay), and RLIMIT_NOFILE raised to its hard limit.

use std::ffi::CString;

use nix::sys::resource::{Resource, getrlimit, setrlimit};
use nix::unistd::{Uid, User, initgroups, setgid, setuid};

/// Raises the soft limit of open descriptors to the hard one; returns the limit.
pub fn raise_nofile() -> Option<u64> {
    let (soft, hard) = getrlimit(Resource::RLIMIT_NOFILE).ok()?;
    if soft < hard && setrlimit(Resource::RLIMIT_NOFILE, hard, hard).is_ok() {
        return Some(hard);
    }
    Some(soft)
}

/// The account `name` (checked at start, before anything is opened).
pub fn lookup(name: &str) -> Result<User, String> {
    match User::from_name(name) {
        Ok(Some(u)) => Ok(u),
        Ok(None) => Err(format!("user {name}: no such user")),
        Err(e) => Err(format!("user {name}: {e}")),
    }
}

/// Becomes `user`: its groups (initgroups), its group, then its uid. Does nothing
/// when the process already runs as that uid (and is not root).
pub fn drop_to(user: &User) -> Result<(), String> {
    if Uid::effective() == user.uid && !user.uid.is_root() {
        return Ok(());
    }
    let name = CString::new(user.name.as_str()).map_err(|_| format!("user {}: a NUL in the name", user.name))?;
    initgroups(&name, user.gid).map_err(|e| format!("user {}: initgroups: {e}", user.name))?;
    setgid(user.gid).map_err(|e| format!("user {}: setgid: {e}", user.name))?;
    setuid(user.uid).map_err(|e| format!("user {}: setuid: {e}", user.name))?;
    if !user.uid.is_root() && setuid(Uid::from_raw(0)).is_ok() {
        return Err(format!("user {}: root could be regained", user.name));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookups() {
        assert!(lookup("root").is_ok());
        assert_eq!(lookup("no-such-user-here").unwrap_err(), "user no-such-user-here: no such user");
        assert!(raise_nofile().is_some_and(|n| n >= 64));
    }
}
