//! FNV-1a, the crate's one hash: a procedural clip's default seed (its name's bytes) and the
//! fingerprint of held limbs (64-bit words of poses and shapes). Fed a byte at a time it is the
//! usual byte-wise FNV-1a.

/// The hash so far.
pub(crate) struct Fnv(pub(crate) u64);

impl Default for Fnv {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    /// Mix in one word (a byte widened to `u64` is mixed in as FNV-1a mixes a byte).
    pub(crate) fn word(&mut self, w: u64) {
        self.0 = (self.0 ^ w).wrapping_mul(0x0000_0100_0000_01b3);
    }

    /// Mix in each value's bits.
    pub(crate) fn floats(&mut self, values: &[f64]) {
        for v in values {
            self.word(v.to_bits());
        }
    }

    /// Mix in each byte.
    pub(crate) fn bytes(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.word(u64::from(b));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Fnv;

    #[test]
    fn bytes_give_the_published_fnv_1a_values() {
        // The 64-bit FNV-1a test vectors (the empty string, "a", "foobar"): the procedural
        // clips' default seeds are those of the byte-wise hash they had before.
        for (text, want) in [
            ("", 0xcbf2_9ce4_8422_2325_u64),
            ("a", 0xaf63_dc4c_8601_ec8c),
            ("foobar", 0x8594_4171_f739_67e8),
        ] {
            let mut h = Fnv::default();
            h.bytes(text.as_bytes());
            assert_eq!(h.0, want, "{text:?}");
        }
    }
}
