//! JSON for the messages `run.mcap` writes every tick and every plan, without serde.
//!
//! serde_json escapes every key of every object it writes, and the keys of these messages
//! are fixed identifiers: writing them as they are took about a fifth of the recording
//! thread's instructions (docs/performance.md, "Recording"). Numbers are formatted as
//! serde_json formats them (the same `zmij` and `itoa` encoders, `null` for a number that
//! is not finite), so the bytes are serde_json's; the tests of `record::mcap` compare the
//! two for every message type written this way.

/// A value that writes itself as JSON.
pub trait Json {
    fn write_json(&self, out: &mut Vec<u8>);
}

impl Json for f64 {
    fn write_json(&self, out: &mut Vec<u8>) {
        if self.is_finite() {
            out.extend_from_slice(zmij::Buffer::new().format_finite(*self).as_bytes());
        } else {
            out.extend_from_slice(b"null");
        }
    }
}

impl Json for u64 {
    fn write_json(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(itoa::Buffer::new().format(*self).as_bytes());
    }
}

impl Json for u32 {
    fn write_json(&self, out: &mut Vec<u8>) {
        u64::from(*self).write_json(out);
    }
}

impl Json for str {
    fn write_json(&self, out: &mut Vec<u8>) {
        // The strings of these messages are a frame's and a mode's name: no escape is
        // needed, but any string is still written right.
        if self.bytes().all(|b| b >= 0x20 && b != b'"' && b != b'\\') {
            out.push(b'"');
            out.extend_from_slice(self.as_bytes());
            out.push(b'"');
        } else {
            serde_json::to_writer(&mut *out, self).expect("a string is always JSON");
        }
    }
}

impl<T: Json + ?Sized> Json for &T {
    fn write_json(&self, out: &mut Vec<u8>) {
        (**self).write_json(out);
    }
}

impl<T: Json> Json for [T] {
    fn write_json(&self, out: &mut Vec<u8>) {
        out.push(b'[');
        for (i, item) in self.iter().enumerate() {
            if i > 0 {
                out.push(b',');
            }
            item.write_json(out);
        }
        out.push(b']');
    }
}

impl<T: Json, const N: usize> Json for [T; N] {
    fn write_json(&self, out: &mut Vec<u8>) {
        self.as_slice().write_json(out);
    }
}

/// Writes an object's fields in order: `object(out).field("x", &x).field("y", &y).end()`.
/// Keys are written as given: identifiers, which JSON needs no escape for.
/// [`json_object`] writes a struct so.
pub fn object(out: &mut Vec<u8>) -> Object<'_> {
    out.push(b'{');
    Object { out, first: true }
}

pub struct Object<'a> {
    out: &'a mut Vec<u8>,
    first: bool,
}

impl Object<'_> {
    pub fn field(mut self, key: &'static str, value: &(impl Json + ?Sized)) -> Self {
        debug_assert!(key.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_'));
        if !self.first {
            self.out.push(b',');
        }
        self.first = false;
        self.out.push(b'"');
        self.out.extend_from_slice(key.as_bytes());
        self.out.extend_from_slice(b"\":");
        value.write_json(self.out);
        self
    }

    pub fn end(self) {
        self.out.push(b'}');
    }
}

/// Implements [`Json`] for a struct as the object of the fields named, in that order: the
/// struct's fields in declaration order give serde's derived `Serialize` output.
macro_rules! json_object {
    ($type:ty { $($field:ident),+ $(,)? }) => {
        impl Json for $type {
            fn write_json(&self, out: &mut Vec<u8>) {
                $crate::json::object(out)
                    $(.field(stringify!($field), &self.$field))+
                    .end();
            }
        }
    };
}
pub(crate) use json_object;
