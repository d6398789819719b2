//! A minimal JSON object writer for the services' `--json` summaries: flat numbers,
//! strings and nested objects are all they print, so a serializer crate is not needed.

use std::fmt::Write;

/// Builds one JSON object, keys in insertion order. Non-finite floats become `null`.
#[derive(Debug, Clone)]
pub struct JsonObject {
    text: String,
    empty: bool,
}

impl Default for JsonObject {
    fn default() -> Self {
        Self::new()
    }
}

impl JsonObject {
    pub fn new() -> Self {
        Self {
            text: String::from("{"),
            empty: true,
        }
    }

    fn key(&mut self, key: &str) {
        if !self.empty {
            self.text.push(',');
        }
        self.empty = false;
        push_string(&mut self.text, key);
        self.text.push(':');
    }

    pub fn u64(&mut self, key: &str, value: u64) -> &mut Self {
        self.key(key);
        let _ = write!(self.text, "{value}");
        self
    }

    pub fn i64(&mut self, key: &str, value: i64) -> &mut Self {
        self.key(key);
        let _ = write!(self.text, "{value}");
        self
    }

    pub fn f64(&mut self, key: &str, value: f64) -> &mut Self {
        self.key(key);
        if value.is_finite() {
            // `{:?}` keeps a decimal point or exponent, so the value reads back as a float.
            let _ = write!(self.text, "{value:?}");
        } else {
            self.text.push_str("null");
        }
        self
    }

    pub fn bool(&mut self, key: &str, value: bool) -> &mut Self {
        self.key(key);
        self.text.push_str(if value { "true" } else { "false" });
        self
    }

    pub fn str(&mut self, key: &str, value: &str) -> &mut Self {
        self.key(key);
        push_string(&mut self.text, value);
        self
    }

    pub fn object(&mut self, key: &str, value: JsonObject) -> &mut Self {
        self.key(key);
        self.text.push_str(&value.finish());
        self
    }

    pub fn finish(mut self) -> String {
        self.text.push('}');
        self.text
    }
}

fn push_string(out: &mut String, s: &str) {
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            c if (c as u32) < 0x20 => {
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_nested_objects_with_escapes_and_nulls() {
        let mut inner = JsonObject::new();
        inner.u64("n", 3).f64("x", 0.5).f64("nan", f64::NAN);
        let mut o = JsonObject::new();
        o.str("name", "a\"b\\c\n")
            .i64("age_ns", -7)
            .bool("ok", true)
            .f64("one", 1.0)
            .object("inner", inner);
        assert_eq!(
            o.finish(),
            r#"{"name":"a\"b\\c\n","age_ns":-7,"ok":true,"one":1.0,"inner":{"n":3,"x":0.5,"nan":null}}"#
        );
        assert_eq!(JsonObject::new().finish(), "{}");
    }
}
