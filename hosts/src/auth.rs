//! Who may publish on a run's Zenoh keys: the bridges that hold the run's key. Every
//! bridged sample carries an HMAC-SHA256 tag of its key expression and bytes under a key
//! the orchestrator draws for the run and gives each host's agent when it joins; a sample
//! whose tag does not verify (a stranger on the Zenoh network publishing on the run's
//! keys) is refused and counted.

use ring::hmac;
use ring::rand::{SecureRandom, SystemRandom};

/// Bytes of a run key.
pub const KEY_BYTES: usize = 32;
/// Bytes of a tag (HMAC-SHA256 truncated: 128 bits).
pub const TAG_BYTES: usize = 16;

/// A run's key.
#[derive(Clone)]
pub struct RunKey {
    bytes: [u8; KEY_BYTES],
    key: hmac::Key,
}

impl std::fmt::Debug for RunKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("RunKey(..)")
    }
}

impl RunKey {
    /// A fresh random key.
    pub fn generate() -> Result<RunKey, String> {
        let mut bytes = [0u8; KEY_BYTES];
        SystemRandom::new()
            .fill(&mut bytes)
            .map_err(|_| "no random numbers from the operating system".to_string())?;
        Ok(RunKey::from_bytes(bytes))
    }

    fn from_bytes(bytes: [u8; KEY_BYTES]) -> RunKey {
        RunKey {
            bytes,
            key: hmac::Key::new(hmac::HMAC_SHA256, &bytes),
        }
    }

    /// The key as hexadecimal, to hand to an agent.
    pub fn to_hex(&self) -> String {
        self.bytes.iter().map(|b| format!("{b:02x}")).collect()
    }

    /// A key from [`RunKey::to_hex`].
    pub fn from_hex(text: &str) -> Option<RunKey> {
        if text.len() != 2 * KEY_BYTES {
            return None;
        }
        let mut bytes = [0u8; KEY_BYTES];
        for (i, b) in bytes.iter_mut().enumerate() {
            *b = u8::from_str_radix(text.get(2 * i..2 * i + 2)?, 16).ok()?;
        }
        Some(RunKey::from_bytes(bytes))
    }

    /// The tag of `payload` published on `key_expr`.
    pub fn tag(&self, key_expr: &str, payload: &[u8]) -> [u8; TAG_BYTES] {
        let mut context = hmac::Context::with_key(&self.key);
        context.update(key_expr.as_bytes());
        context.update(&[0]);
        context.update(payload);
        let mut tag = [0u8; TAG_BYTES];
        tag.copy_from_slice(&context.sign().as_ref()[..TAG_BYTES]);
        tag
    }

    /// Whether `tag` is the tag of `payload` on `key_expr` (in constant time).
    pub fn verify(&self, key_expr: &str, payload: &[u8], tag: &[u8]) -> bool {
        let expected = self.tag(key_expr, payload);
        tag.len() == TAG_BYTES
            && expected
                .iter()
                .zip(tag)
                .fold(0u8, |diff, (a, b)| diff | (a ^ b))
                == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tag_verifies_only_for_its_key_expression_bytes_and_key() {
        let key = RunKey::generate().unwrap();
        let tag = key.tag("scmpc/run/x/to/main/plan", b"bytes");
        assert!(key.verify("scmpc/run/x/to/main/plan", b"bytes", &tag));
        assert!(!key.verify("scmpc/run/x/to/main/plan", b"bytez", &tag));
        assert!(!key.verify("scmpc/run/x/to/main/estimate", b"bytes", &tag));
        assert!(!key.verify("scmpc/run/x/to/main/plan", b"bytes", &tag[..8]));
        let other = RunKey::generate().unwrap();
        assert!(!other.verify("scmpc/run/x/to/main/plan", b"bytes", &tag));
        let again = RunKey::from_hex(&key.to_hex()).unwrap();
        assert!(again.verify("scmpc/run/x/to/main/plan", b"bytes", &tag));
        assert!(RunKey::from_hex("zz").is_none());
    }
}
