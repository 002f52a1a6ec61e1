//! Fixed-size arrays read from TOML arrays of exactly that many elements: serde's
//! arrays take the first N elements and drop the rest without a word (seven `home`
//! values or five rails were accepted so).

use serde::{de::Error, Deserialize, Deserializer};

/// A value read exactly from a TOML value.
pub trait Exact: Sized {
    fn exact(v: toml::Value) -> Result<Self, String>;
}

impl Exact for f64 {
    fn exact(v: toml::Value) -> Result<Self, String> {
        match v {
            toml::Value::Float(f) => Ok(f),
            toml::Value::Integer(i) => Ok(i as f64),
            other => Err(format!("expected a number, got {}", other.type_str())),
        }
    }
}

impl Exact for i8 {
    fn exact(v: toml::Value) -> Result<Self, String> {
        match v {
            toml::Value::Integer(i) => i8::try_from(i).map_err(|_| format!("{i} is out of range")),
            other => Err(format!("expected an integer, got {}", other.type_str())),
        }
    }
}

impl<T: Exact, const N: usize> Exact for [T; N] {
    fn exact(v: toml::Value) -> Result<Self, String> {
        let toml::Value::Array(items) = v else {
            return Err(format!("expected an array of {N}, got {}", v.type_str()));
        };
        if items.len() != N {
            return Err(format!("expected {N} values, got {}", items.len()));
        }
        let items: Vec<T> = items.into_iter().map(T::exact).collect::<Result<_, _>>()?;
        items.try_into().map_err(|_| format!("expected {N} values"))
    }
}

pub fn de<'de, D: Deserializer<'de>, T: Exact>(d: D) -> Result<T, D::Error> {
    T::exact(toml::Value::deserialize(d)?).map_err(D::Error::custom)
}

pub fn de_some<'de, D: Deserializer<'de>, T: Exact>(d: D) -> Result<Option<T>, D::Error> {
    de(d).map(Some)
}
