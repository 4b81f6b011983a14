//! Settings that take one of a few names: typed enums that read and write
//! as those names (so config.toml, checkpoints and sweep keys are the same
//! text as when they were strings), parsed once where the settings are
//! read, with an error that names the key, the value and every choice.
//! The enums live with their stage (`stages/*/settings.rs`); this holds
//! the macro that makes them and the checks stages share.

use anyhow::{bail, Result};

/// `name_enum!(/// doc, Type, "section.key", { /// doc, Variant = "name", ... })`:
/// the enum, `name()`, `parse()`, `NAMES`, and serde as the name.
macro_rules! name_enum {
    ($(#[$m:meta])* $name:ident, $key:literal, { $($(#[$vm:meta])* $var:ident = $text:literal),+ $(,)? }) => {
        $(#[$m])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        pub enum $name {
            $($(#[$vm])* $var),+
        }

        impl $name {
            /// Every accepted name, in declaration order.
            pub const NAMES: &'static [&'static str] = &[$($text),+];
            /// The setting's key.
            pub const KEY: &'static str = $key;

            pub fn name(self) -> &'static str {
                match self {
                    $(Self::$var => $text),+
                }
            }

            pub fn parse(s: &str) -> Result<Self, String> {
                match s {
                    $($text => Ok(Self::$var),)+
                    other => Err($crate::train::settings::choice_error($key, Self::NAMES, other)),
                }
            }
        }

        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(self.name())
            }
        }

        impl serde::Serialize for $name {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_str(self.name())
            }
        }

        impl<'de> serde::Deserialize<'de> for $name {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let s = String::deserialize(d)?;
                Self::parse(&s).map_err(<D::Error as serde::de::Error>::custom)
            }
        }
    };
}
pub(crate) use name_enum;

/// "KEY must be 'a', 'b' or 'c', not 'x'".
pub fn choice_error(key: &str, names: &[&str], got: &str) -> String {
    let q: Vec<String> = names.iter().map(|n| format!("'{n}'")).collect();
    let list = match q.len() {
        1 => q[0].clone(),
        n => format!("{} or {}", q[..n - 1].join(", "), q[n - 1]),
    };
    format!("{key} must be {list}, not '{got}'")
}

/// A stage's high-frequency loss settings (`SECTION.lambda_hf`,
/// `SECTION.hf_percentile`), checked.
pub(crate) fn check_hf(section: &str, lambda: f32, pct: f32) -> Result<()> {
    if !(lambda >= 0.0 && lambda.is_finite()) {
        bail!("{section}.lambda_hf must be non-negative and finite, not {lambda}");
    }
    if !(0.0..=100.0).contains(&pct) {
        bail!("{section}.hf_percentile must be in [0, 100], not {pct}");
    }
    Ok(())
}
