//! The one rule for numbers in JSON output. JSON has no NaN or infinity, and `null` would hide which of
//! them a check produced, so a finite value is written as a number and a non-finite one as the string `"NaN"`,
//! `"inf"` or `"-inf"`. Result types apply it per field with
//! `#[serde(serialize_with = "crate::base::json::num")]` (or [`opt_num`]); a name → number object is a
//! [`Named`].

use serde::Serializer;

/// `serialize_with` helper for an `f64` field.
pub fn num<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    if v.is_finite() {
        s.serialize_f64(*v)
    } else {
        s.collect_str(v)
    }
}

/// `serialize_with` helper for an `Option<f64>` field: `None` is `null`.
pub(crate) fn opt_num<S: Serializer>(v: &Option<f64>, s: S) -> Result<S::Ok, S::Error> {
    match v {
        Some(v) => num(v, s),
        None => s.serialize_none(),
    }
}

/// An object mapping each name to its number (parameters, inputs), in the given order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Named(pub Vec<(String, f64)>);

impl Named {
    pub fn new<'a>(pairs: impl IntoIterator<Item = (&'a str, f64)>) -> Named {
        Named(pairs.into_iter().map(|(k, v)| (k.to_string(), v)).collect())
    }
}

impl serde::Serialize for Named {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        struct Num(f64);
        impl serde::Serialize for Num {
            fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                num(&self.0, s)
            }
        }
        let mut m = s.serialize_map(Some(self.0.len()))?;
        for (k, v) in &self.0 {
            m.serialize_entry(k, &Num(*v))?;
        }
        m.end()
    }
}

/// A number as a `serde_json::Value` under the same rule (the tests' view of it).
#[cfg(test)]
fn value(v: f64) -> serde_json::Value {
    if v.is_finite() {
        serde_json::Value::from(v)
    } else {
        serde_json::Value::String(v.to_string())
    }
}

/// An object mapping each name to its value, as [`value`] writes numbers.
#[cfg(test)]
fn named<'a>(pairs: impl IntoIterator<Item = (&'a str, f64)>) -> serde_json::Value {
    serde_json::Value::Object(pairs.into_iter().map(|(k, v)| (k.to_string(), value(v))).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(serde::Serialize)]
    struct One(#[serde(serialize_with = "num")] f64);

    #[derive(serde::Serialize)]
    struct Maybe(#[serde(serialize_with = "opt_num")] Option<f64>);

    #[test]
    fn finite_numbers_stay_numbers_and_the_others_are_named() {
        for v in [0.125, 268.0, -2.5e-300, 0.0, f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert_eq!(serde_json::to_value(One(v)).unwrap(), value(v), "{v}");
        }
        assert_eq!(serde_json::to_string(&One(268.0)).unwrap(), "268.0");
        assert_eq!(value(f64::NAN), serde_json::json!("NaN"));
        assert_eq!(value(f64::INFINITY), serde_json::json!("inf"));
        assert_eq!(value(f64::NEG_INFINITY), serde_json::json!("-inf"));
        assert_eq!(serde_json::to_value(Maybe(None)).unwrap(), serde_json::Value::Null);
        assert_eq!(serde_json::to_value(Maybe(Some(f64::NAN))).unwrap(), value(f64::NAN));
        assert_eq!(named([("n", 50.0), ("a", f64::INFINITY)]), serde_json::json!({"n": 50.0, "a": "inf"}));
        assert_eq!(serde_json::to_value(Named::new([("n", 50.0), ("a", f64::INFINITY)])).unwrap(), named([("n", 50.0), ("a", f64::INFINITY)]));
    }
}
