//! The fields of every type that crosses a process boundary, as a program in another
//! language must lay them out (`scmpc schema`'s `types`, made by `runtime::layout`).
//! Offsets and sizes come from the compiler; each field's name and type are written once,
//! beside the type's definition ([`layouts!`](crate::layouts)), and `runtime::layout`'s
//! tests check that the fields cover every byte that is not alignment padding.

use serde::Serialize;

/// One field of a `#[repr(C)]` type.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Field {
    pub name: &'static str,
    /// Bytes from the start of the type.
    pub offset: usize,
    /// Rust spelling ([`type_label`]).
    #[serde(rename = "type")]
    pub ty: String,
    pub size: usize,
}

/// A type whose fields are described ([`layouts!`](crate::layouts)).
pub trait Layout {
    /// Its fields, in memory order.
    fn fields() -> Vec<Field>;
}

/// The Rust spelling of `T` in a layout: `u32`, `[f64; 3]`, `[[u128; 2]; 6]`, another
/// type of ours by its iceoryx2 name (`scmpc::Header`).
pub fn type_label<T>() -> String {
    let name = std::any::type_name::<T>();
    let mut label = String::with_capacity(name.len());
    let mut word = String::new();
    for c in name.chars() {
        if c.is_alphanumeric() || c == '_' || c == ':' {
            word.push(c);
        } else {
            label.push_str(&ours(&word));
            word.clear();
            label.push(c);
        }
    }
    label.push_str(&ours(&word));
    label
}

/// A path (`protocol::messages::Header`) as the iceoryx2 name of the type it ends with.
fn ours(word: &str) -> String {
    match word.rsplit_once("::") {
        Some((_, name)) => format!("scmpc::{name}"),
        None => word.to_string(),
    }
}

/// Implements [`Layout`] for each type from its fields: `Type { name: type, ... }`.
#[macro_export]
macro_rules! layouts {
    ($($t:ident { $($field:ident: $ty:ty),* $(,)? })*) => {$(
        impl $crate::layout::Layout for $t {
            fn fields() -> Vec<$crate::layout::Field> {
                vec![$($crate::layout::Field {
                    name: stringify!($field),
                    offset: core::mem::offset_of!($t, $field),
                    ty: $crate::layout::type_label::<$ty>(),
                    size: core::mem::size_of::<$ty>(),
                }),*]
            }
        }
    )*};
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_label_spells_arrays_with_their_lengths_and_our_types_by_their_iceoryx2_names() {
        use super::type_label;
        assert_eq!(type_label::<[[f64; 4]; 3]>(), "[[f64; 4]; 3]");
        assert_eq!(type_label::<crate::Header>(), "scmpc::Header");
        assert_eq!(type_label::<[crate::Track; 2]>(), "[scmpc::Track; 2]");
    }
}
