//! Settings enums named once. `named_enum!` gives an enum of the library's
//! settings its command-line names (`NAMES`, `name()`), `FromStr` and
//! `Display` from one table, so the CLI (a clap parser over `NAMES`), the
//! Python package (the strings it passes) and the docs read the same names
//! instead of each keeping a copy.

/// Implements `NAMES`, `name()`, `FromStr` and `Display` for `$ty` from
/// `Variant => "name"` pairs; `$what` names the setting in the error
/// ("'sideways' is not an up axis (expected one of: y, z)").
#[macro_export]
macro_rules! named_enum {
    ($ty:ident, $what:literal, { $($variant:ident => $name:literal),+ $(,)? }) => {
        impl $ty {
            /// Every value's name, as the command line and the Python package take it.
            pub const NAMES: &'static [&'static str] = &[$($name),+];

            /// This value's name.
            pub fn name(self) -> &'static str {
                match self {
                    $($ty::$variant => $name),+
                }
            }
        }

        impl ::std::str::FromStr for $ty {
            type Err = String;
            fn from_str(s: &str) -> Result<Self, String> {
                match s {
                    $($name => Ok($ty::$variant),)+
                    _ => Err(format!("'{s}' is not {} (expected one of: {})", $what, $ty::NAMES.join(", "))),
                }
            }
        }

        impl ::std::fmt::Display for $ty {
            fn fmt(&self, f: &mut ::std::fmt::Formatter<'_>) -> ::std::fmt::Result {
                f.write_str(self.name())
            }
        }
    };
}

#[cfg(test)]
mod tests {
    #[derive(Clone, Copy, Debug, PartialEq)]
    enum Side {
        Left,
        Right,
    }
    crate::named_enum!(Side, "a side", { Left => "left", Right => "right" });

    #[test]
    fn names_parse_and_print_back() {
        for n in Side::NAMES {
            assert_eq!(n.parse::<Side>().unwrap().to_string(), *n);
        }
        assert_eq!("right".parse::<Side>(), Ok(Side::Right));
        assert_eq!(Side::Left.name(), "left");
        assert_eq!("up".parse::<Side>().unwrap_err(), "'up' is not a side (expected one of: left, right)");
    }
}
