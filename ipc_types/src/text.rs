//! Fixed-size, NUL-padded UTF-8 text fields: how labels, phrases and names travel on the wire.

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

#[cfg(test)]
mod tests {
    use super::*;

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
