//! Fixed-size, NUL-padded UTF-8 text fields (how labels, phrases and names travel on the wire),
//! and error text fit for a user.

/// Reads a NUL-padded UTF-8 buffer. Invalid UTF-8 is cut at the first invalid byte.
pub fn fixed_str(buffer: &[u8]) -> &str {
    let len = buffer.iter().position(|b| *b == 0).unwrap_or(buffer.len());
    match core::str::from_utf8(&buffer[..len]) {
        Ok(s) => s,
        Err(e) => core::str::from_utf8(&buffer[..e.valid_up_to()]).unwrap_or(""),
    }
}

/// Writes `text` into a NUL-padded buffer, cutting at a character boundary if it does not fit.
/// Returns `true` when the whole text fitted.
pub fn write_fixed_str(buffer: &mut [u8], text: &str) -> bool {
    let mut len = text.len().min(buffer.len());
    while !text.is_char_boundary(len) {
        len -= 1;
    }
    buffer[..len].copy_from_slice(&text.as_bytes()[..len]);
    buffer[len..].fill(0);
    len == text.len()
}

/// `message` without the source locations some libraries append to their errors (Zenoh's end
/// in ` at /home/…/.cargo/registry/src/…/endpoint.rs:615.`): a user reads what went wrong, not
/// where in a dependency it was noticed. Each ` at <path>.rs:<line>` goes, with a `.` right after it.
pub fn without_source_locations(message: &str) -> String {
    let mut out = String::with_capacity(message.len());
    let mut rest = message;
    while let Some(at) = rest.find(" at ") {
        let after = &rest[at + 4..];
        let token_len = after.find(char::is_whitespace).unwrap_or(after.len());
        let token = &after[..token_len];
        match source_location_len(token) {
            Some(len) => {
                out.push_str(&rest[..at]);
                rest = &after[len..];
            }
            None => {
                out.push_str(&rest[..at + 4]);
                rest = after;
            }
        }
    }
    out.push_str(rest);
    out
}

/// The length of a `<path>.rs:<line>` (with an optional trailing `.`) at the start of `token`.
fn source_location_len(token: &str) -> Option<usize> {
    let rs = token.find(".rs:")?;
    let digits = token[rs + 4..].bytes().take_while(u8::is_ascii_digit).count();
    if digits == 0 || !token[..rs].contains('/') {
        return None;
    }
    let end = rs + 4 + digits;
    Some(if token[end..].starts_with('.') { end + 1 } else { end })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn source_locations_leave_error_text() {
        let zenoh = "Can not create a new TCP listener bound to tcp/127.0.0.1:7447: Address in use (os error 98) \
                     at /root/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/zenoh-link-tcp-1.10.2/src/unicast.rs:340.";
        assert_eq!(
            without_source_locations(zenoh),
            "Can not create a new TCP listener bound to tcp/127.0.0.1:7447: Address in use (os error 98)"
        );
        let nested = "open: a at /x/y.rs:1. caused by b at /x/z.rs:22.";
        assert_eq!(without_source_locations(nested), "open: a caused by b");
        for kept in ["look at the map", "at 10:30", "fails at line.rs:3 (no folder)", "at /etc/op3dsg/robot.toml"] {
            assert_eq!(without_source_locations(kept), kept);
        }
    }

    #[test]
    fn fixed_strings_round_trip_and_cut_at_char_boundaries() {
        let mut buf = [0u8; 8];
        assert!(write_fixed_str(&mut buf, "knob"));
        assert_eq!(fixed_str(&buf), "knob");
        assert!(!write_fixed_str(&mut buf, "drawer handle"));
        assert_eq!(fixed_str(&buf), "drawer h");
        assert!(!write_fixed_str(&mut buf, "ÄÄÄÄÄ")); // 10 bytes, cut to 8 = 4 chars
        assert_eq!(fixed_str(&buf), "ÄÄÄÄ");
        assert!(write_fixed_str(&mut buf, "12345678"));
        assert_eq!(fixed_str(&buf), "12345678");
    }
}
