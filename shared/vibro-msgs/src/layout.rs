//! How the wire types are declared: one macro that emits the `#[repr(C)]` struct, its
//! iceoryx2 type name, a zero value, and a table of its fields, and that refuses at
//! compile time a struct with implicit padding or with a field that is not a plain number.
//!
//! The field table ([`FieldLayout`]) is what `docs/messages.md` is checked against, so the
//! published byte layout cannot drift from the code.

/// The byte layout of one field of a wire type.
#[derive(Clone, Copy, Debug)]
pub struct FieldLayout {
    /// The field's name, as in the Rust struct and in `docs/messages.md`.
    pub name: &'static str,
    /// Offset from the start of the struct, in bytes (`core::mem::offset_of!`).
    pub offset_bytes: usize,
    /// Size in bytes (`core::mem::size_of` of the field's type).
    pub size_bytes: usize,
    rust_type: fn() -> &'static str,
}

impl FieldLayout {
    #[doc(hidden)]
    pub const fn new(
        name: &'static str,
        offset_bytes: usize,
        size_bytes: usize,
        rust_type: fn() -> &'static str,
    ) -> Self {
        Self {
            name,
            offset_bytes,
            size_bytes,
            rust_type,
        }
    }

    /// The field's Rust type with constants resolved, e.g. `[[f64; 3]; 32]`.
    pub fn rust_type(&self) -> &'static str {
        (self.rust_type)()
    }

    /// The field's type in C notation, e.g. `double[32][3]`, `uint64_t`, as written in
    /// `docs/messages.md`.
    pub fn c_type(&self) -> String {
        c_type(self.rust_type())
    }
}

/// Converts a Rust plain-number type (`u64`, `[[f64; 3]; 32]`) into C notation
/// (`uint64_t`, `double[32][3]`). Unknown names are returned unchanged, so a mismatch shows.
fn c_type(rust: &str) -> String {
    let mut dims = Vec::new();
    let mut inner = rust.trim();
    // `[[f64; 3]; 32]` is 32 rows of `[f64; 3]`: peel the outer length first.
    while let Some(body) = inner.strip_prefix('[').and_then(|s| s.strip_suffix(']')) {
        match body.rsplit_once(';') {
            Some((element, len)) => {
                dims.push(len.trim().to_string());
                inner = element.trim();
            }
            None => break,
        }
    }
    let scalar = match inner {
        "u8" => "uint8_t",
        "u16" => "uint16_t",
        "u32" => "uint32_t",
        "u64" => "uint64_t",
        "i8" => "int8_t",
        "i16" => "int16_t",
        "i32" => "int32_t",
        "i64" => "int64_t",
        "f32" => "float",
        "f64" => "double",
        other => other,
    };
    let mut out = scalar.to_string();
    for d in dims {
        out.push('[');
        out.push_str(&d);
        out.push(']');
    }
    out
}

/// Types whose every bit pattern is a valid value and which contain no padding: the only
/// field types a wire struct may have. Sealed: implemented here for the plain numbers and
/// arrays of them.
pub trait Plain: Copy + private::Sealed {
    /// All bits zero.
    const ZERO: Self;
}

mod private {
    pub trait Sealed {}
}

macro_rules! plain {
    ($($t:ty = $zero:expr),* $(,)?) => {
        $(
            impl private::Sealed for $t {}
            impl Plain for $t {
                const ZERO: Self = $zero;
            }
        )*
    };
}

plain!(
    u8 = 0,
    u16 = 0,
    u32 = 0,
    u64 = 0,
    i8 = 0,
    i16 = 0,
    i32 = 0,
    i64 = 0,
    f32 = 0.0,
    f64 = 0.0,
);

impl<T: Plain, const N: usize> private::Sealed for [T; N] {}
impl<T: Plain, const N: usize> Plain for [T; N] {
    const ZERO: Self = [T::ZERO; N];
}

/// Declares a wire type. Emits the struct (`#[repr(C)]`, `Clone, Copy, Debug, PartialEq`,
/// iceoryx2 `ZeroCopySend` with the given type name), `TYPE_NAME`, `ZEROED`, `FIELDS`,
/// `Default`, `as_bytes`, and two compile-time checks: every field type is [`Plain`], and
/// the struct's size equals the sum of its fields' sizes (no implicit padding).
macro_rules! wire_struct {
    (
        $(#[$smeta:meta])*
        type_name = $tn:tt;
        pub struct $name:ident {
            $( $(#[$fmeta:meta])* pub $field:ident : $ty:ty, )*
        }
    ) => {
        $(#[$smeta])*
        #[repr(C)]
        #[derive(Clone, Copy, Debug, PartialEq)]
        #[cfg_attr(feature = "ipc", derive(::iceoryx2::prelude::ZeroCopySend), type_name($tn))]
        pub struct $name {
            $( $(#[$fmeta])* pub $field: $ty, )*
        }

        impl $name {
            /// The iceoryx2 payload type name (see `docs/messages.md` for the version rule).
            pub const TYPE_NAME: &'static str = $tn;
            /// Every field zero.
            pub const ZEROED: Self = Self { $( $field: <$ty as $crate::layout::Plain>::ZERO, )* };
            /// The byte layout of every field, in declaration order.
            pub const FIELDS: &'static [$crate::layout::FieldLayout] = &[
                $(
                    $crate::layout::FieldLayout::new(
                        stringify!($field),
                        ::core::mem::offset_of!($name, $field),
                        ::core::mem::size_of::<$ty>(),
                        ::core::any::type_name::<$ty>,
                    ),
                )*
            ];

            /// The message's bytes as they travel through shared memory (native byte order).
            pub fn as_bytes(&self) -> &[u8] {
                // SAFETY: `Self` is `#[repr(C)]`, every field is `Plain` (integers, floats
                // and arrays of them: no pointers, every byte initialised) and the
                // compile-time check below proves there are no padding bytes, so all
                // `size_of::<Self>()` bytes behind `self` are initialised `u8`s that live
                // as long as `&self`.
                unsafe {
                    ::core::slice::from_raw_parts(
                        (self as *const Self).cast::<u8>(),
                        ::core::mem::size_of::<Self>(),
                    )
                }
            }

            /// The message from its bytes (native byte order), e.g. read from a socket;
            /// `None` unless `bytes` is exactly `size_of::<Self>()` long. Counts are
            /// not checked: call `validate` before indexing the arrays.
            pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
                if bytes.len() != ::core::mem::size_of::<Self>() {
                    return None;
                }
                let mut out = Self::ZEROED;
                // SAFETY: as for `as_bytes`, every byte of `Self` is part of a plain
                // integer or float field, for which every bit pattern is valid; the
                // source holds exactly `size_of::<Self>()` bytes and does not overlap
                // the local `out`.
                unsafe {
                    ::core::ptr::copy_nonoverlapping(
                        bytes.as_ptr(),
                        (&mut out as *mut Self).cast::<u8>(),
                        bytes.len(),
                    );
                }
                Some(out)
            }
        }

        impl Default for $name {
            fn default() -> Self {
                Self::ZEROED
            }
        }

        const _: () = {
            const fn field_is_plain<T: $crate::layout::Plain>() {}
            $( field_is_plain::<$ty>(); )*
            assert!(
                ::core::mem::size_of::<$name>() == 0 $( + ::core::mem::size_of::<$ty>() )*,
                concat!(stringify!($name), " has implicit padding: add explicit _pad fields")
            );
        };
    };
}

pub(crate) use wire_struct;

#[cfg(test)]
mod tests {
    use super::c_type;

    #[test]
    fn rust_types_convert_to_c_notation() {
        assert_eq!(c_type("u64"), "uint64_t");
        assert_eq!(c_type("i64"), "int64_t");
        assert_eq!(c_type("[u8; 4]"), "uint8_t[4]");
        assert_eq!(c_type("[f64; 3]"), "double[3]");
        assert_eq!(c_type("[[f64; 3]; 32]"), "double[32][3]");
        assert_eq!(c_type("[[f64; 3]; 3]"), "double[3][3]");
        assert_eq!(c_type("String"), "String");
    }
}
