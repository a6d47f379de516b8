//! A value of a type with every optional part present, made from the type alone
//! ([`filled`]): what the CSV columns are derived from (see [`super::columns`]), so a field
//! added to a row's part is a column without a template written by hand.
//!
//! The value is built by deserialising the type from a source that answers every request
//! the type makes: a number (0) for a number, `false` for a boolean, an empty string for a
//! string, `Some` for an `Option`, one element for a list, every variant of an enum used as
//! a map key (the sub-stages of a per-stage map), the first variant of an enum used as a
//! value, and every field of a struct. Types that must look at the data first (serde's
//! `flatten`, untagged or internally tagged enums) cannot be filled this way: fill their
//! parts instead.

use serde::de::{self, DeserializeOwned, DeserializeSeed, IntoDeserializer, Visitor};
use std::cell::Cell;
use std::fmt;
use std::rc::Rc;

/// Why a type cannot be filled.
#[derive(Debug)]
pub struct FillError(String);

impl fmt::Display for FillError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "cannot fill the type: {}", self.0)
    }
}

impl std::error::Error for FillError {}

impl de::Error for FillError {
    fn custom<T: fmt::Display>(msg: T) -> Self {
        FillError(msg.to_string())
    }
}

/// A value of `T` with every optional part present (see the module docs).
pub fn filled<T: DeserializeOwned>() -> Result<T, FillError> {
    T::deserialize(Filler)
}

/// `fn deserialize_x(self, v) { v.visit_y(zero) }` for each listed number type.
macro_rules! filled_numbers {
    ($($($name:ident),+ => $visit:ident($zero:expr);)+) => {
        $($(
            fn $name<V: Visitor<'de>>(self, v: V) -> Result<V::Value, FillError> {
                v.$visit($zero)
            }
        )+)+
    };
}

/// The source of a filled value.
struct Filler;

impl<'de> de::Deserializer<'de> for Filler {
    type Error = FillError;

    fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, FillError> {
        Err(FillError(
            "a part looks at the data before it knows its type (serde flatten, an untagged or internally tagged \
             enum): fill its parts one by one"
                .into(),
        ))
    }

    fn deserialize_bool<V: Visitor<'de>>(self, v: V) -> Result<V::Value, FillError> {
        v.visit_bool(false)
    }

    filled_numbers! {
        deserialize_i8, deserialize_i16, deserialize_i32, deserialize_i64 => visit_i64(0);
        deserialize_u8, deserialize_u16, deserialize_u32, deserialize_u64 => visit_u64(0);
        deserialize_f32, deserialize_f64 => visit_f64(0.0);
    }

    fn deserialize_char<V: Visitor<'de>>(self, v: V) -> Result<V::Value, FillError> {
        v.visit_char('x')
    }

    fn deserialize_str<V: Visitor<'de>>(self, v: V) -> Result<V::Value, FillError> {
        v.visit_str("")
    }

    fn deserialize_string<V: Visitor<'de>>(self, v: V) -> Result<V::Value, FillError> {
        v.visit_str("")
    }

    fn deserialize_bytes<V: Visitor<'de>>(self, _: V) -> Result<V::Value, FillError> {
        Err(FillError("bytes are not a cell".into()))
    }

    fn deserialize_byte_buf<V: Visitor<'de>>(self, _: V) -> Result<V::Value, FillError> {
        Err(FillError("bytes are not a cell".into()))
    }

    fn deserialize_option<V: Visitor<'de>>(self, v: V) -> Result<V::Value, FillError> {
        v.visit_some(Filler)
    }

    fn deserialize_unit<V: Visitor<'de>>(self, v: V) -> Result<V::Value, FillError> {
        v.visit_unit()
    }

    fn deserialize_unit_struct<V: Visitor<'de>>(self, _: &'static str, v: V) -> Result<V::Value, FillError> {
        v.visit_unit()
    }

    fn deserialize_newtype_struct<V: Visitor<'de>>(self, _: &'static str, v: V) -> Result<V::Value, FillError> {
        v.visit_newtype_struct(Filler)
    }

    fn deserialize_seq<V: Visitor<'de>>(self, v: V) -> Result<V::Value, FillError> {
        v.visit_seq(Elements(1))
    }

    fn deserialize_tuple<V: Visitor<'de>>(self, len: usize, v: V) -> Result<V::Value, FillError> {
        v.visit_seq(Elements(len))
    }

    fn deserialize_tuple_struct<V: Visitor<'de>>(
        self,
        _: &'static str,
        len: usize,
        v: V,
    ) -> Result<V::Value, FillError> {
        v.visit_seq(Elements(len))
    }

    fn deserialize_map<V: Visitor<'de>>(self, v: V) -> Result<V::Value, FillError> {
        v.visit_map(Entries { next: 0, variants: Rc::new(Cell::new(None)) })
    }

    fn deserialize_struct<V: Visitor<'de>>(
        self,
        _: &'static str,
        fields: &'static [&'static str],
        v: V,
    ) -> Result<V::Value, FillError> {
        v.visit_map(Fields { fields, next: 0 })
    }

    fn deserialize_enum<V: Visitor<'de>>(
        self,
        _: &'static str,
        variants: &'static [&'static str],
        v: V,
    ) -> Result<V::Value, FillError> {
        let first = variants.first().ok_or_else(|| FillError("an enum without variants".into()))?;
        v.visit_enum(Variant(first))
    }

    fn deserialize_identifier<V: Visitor<'de>>(self, v: V) -> Result<V::Value, FillError> {
        v.visit_str("")
    }

    fn deserialize_ignored_any<V: Visitor<'de>>(self, v: V) -> Result<V::Value, FillError> {
        v.visit_unit()
    }
}

/// The elements of a filled list or tuple.
struct Elements(usize);

impl<'de> de::SeqAccess<'de> for Elements {
    type Error = FillError;

    fn next_element_seed<T: DeserializeSeed<'de>>(&mut self, seed: T) -> Result<Option<T::Value>, FillError> {
        if self.0 == 0 {
            return Ok(None);
        }
        self.0 -= 1;
        seed.deserialize(Filler).map(Some)
    }
}

/// The fields of a filled struct, each filled.
struct Fields {
    fields: &'static [&'static str],
    next: usize,
}

impl<'de> de::MapAccess<'de> for Fields {
    type Error = FillError;

    fn next_key_seed<K: DeserializeSeed<'de>>(&mut self, seed: K) -> Result<Option<K::Value>, FillError> {
        let Some(name) = self.fields.get(self.next) else { return Ok(None) };
        self.next += 1;
        seed.deserialize(IntoDeserializer::<FillError>::into_deserializer(*name)).map(Some)
    }

    fn next_value_seed<V: DeserializeSeed<'de>>(&mut self, seed: V) -> Result<V::Value, FillError> {
        seed.deserialize(Filler)
    }
}

/// The entries of a filled map: one per variant of its key's enum (the key's first request
/// says how many there are).
struct Entries {
    next: usize,
    variants: Rc<Cell<Option<usize>>>,
}

impl<'de> de::MapAccess<'de> for Entries {
    type Error = FillError;

    fn next_key_seed<K: DeserializeSeed<'de>>(&mut self, seed: K) -> Result<Option<K::Value>, FillError> {
        if self.variants.get().is_some_and(|n| self.next >= n) {
            return Ok(None);
        }
        let key = seed.deserialize(Key { index: self.next, variants: self.variants.clone() })?;
        self.next += 1;
        Ok(Some(key))
    }

    fn next_value_seed<V: DeserializeSeed<'de>>(&mut self, seed: V) -> Result<V::Value, FillError> {
        seed.deserialize(Filler)
    }
}

/// The key of a filled map's entry `index`: that variant of the key's enum.
struct Key {
    index: usize,
    variants: Rc<Cell<Option<usize>>>,
}

impl<'de> de::Deserializer<'de> for Key {
    type Error = FillError;

    fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, FillError> {
        Err(FillError(
            "a map whose keys are not an enum (e.g. the sub-stages), or a struct with serde flatten, cannot be \
             filled: fill its parts one by one"
                .into(),
        ))
    }

    fn deserialize_enum<V: Visitor<'de>>(
        self,
        _: &'static str,
        variants: &'static [&'static str],
        v: V,
    ) -> Result<V::Value, FillError> {
        self.variants.set(Some(variants.len()));
        let name = variants.get(self.index).ok_or_else(|| FillError("an enum without variants".into()))?;
        v.visit_enum(Variant(name))
    }

    serde::forward_to_deserialize_any! {
        bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes byte_buf option unit
        unit_struct newtype_struct seq tuple tuple_struct map struct identifier ignored_any
    }
}

/// A unit variant by name (a variant with data is filled too).
struct Variant(&'static str);

impl<'de> de::EnumAccess<'de> for Variant {
    type Error = FillError;
    type Variant = Filler;

    fn variant_seed<S: DeserializeSeed<'de>>(self, seed: S) -> Result<(S::Value, Filler), FillError> {
        let v = seed.deserialize(IntoDeserializer::<FillError>::into_deserializer(self.0))?;
        Ok((v, Filler))
    }
}

impl<'de> de::VariantAccess<'de> for Filler {
    type Error = FillError;

    fn unit_variant(self) -> Result<(), FillError> {
        Ok(())
    }

    fn newtype_variant_seed<T: DeserializeSeed<'de>>(self, seed: T) -> Result<T::Value, FillError> {
        seed.deserialize(Filler)
    }

    fn tuple_variant<V: Visitor<'de>>(self, len: usize, v: V) -> Result<V::Value, FillError> {
        v.visit_seq(Elements(len))
    }

    fn struct_variant<V: Visitor<'de>>(self, fields: &'static [&'static str], v: V) -> Result<V::Value, FillError> {
        v.visit_map(Fields { fields, next: 0 })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mpm_core::Substage;
    use serde::Deserialize;
    use std::collections::BTreeMap;

    #[derive(Debug, Deserialize, PartialEq)]
    enum Kind {
        A,
        B,
    }

    #[derive(Debug, Deserialize)]
    struct Inner {
        x: Option<f64>,
        flags: Vec<bool>,
    }

    #[derive(Debug, Deserialize)]
    struct Outer {
        n: u64,
        name: String,
        kind: Kind,
        inner: Option<Inner>,
        per_stage: BTreeMap<Substage, Option<u32>>,
        pair: [f64; 2],
        lists: Vec<Vec<usize>>,
    }

    /// Every optional part is present, lists have one element, an enum-keyed map every key.
    #[test]
    fn every_part_is_present() {
        let o: Outer = filled().unwrap();
        assert_eq!((o.n, o.name.as_str(), o.kind), (0, "", Kind::A));
        let inner = o.inner.unwrap();
        assert_eq!((inner.x, inner.flags), (Some(0.0), vec![false]));
        assert_eq!(o.per_stage.len(), Substage::ALL.len());
        assert!(o.per_stage.values().all(|v| *v == Some(0)));
        assert_eq!((o.pair, o.lists), ([0.0, 0.0], vec![vec![0]]));
    }

    /// A type that needs the data first is refused with what to do.
    #[test]
    fn flattened_types_are_refused() {
        #[derive(Debug, Deserialize)]
        struct Flat {
            #[serde(flatten)]
            _inner: Inner,
        }
        let err = filled::<Flat>().unwrap_err().to_string();
        assert!(err.contains("parts one by one"), "{err}");
    }
}
