//! The units an [`Axis`](super::Axis) moves in, as types: a stage's
//! positions are [`Mm`], a mount's [`Deg`]. Each is a plain `f64` inside
//! (serialised as the bare number), so the types cost nothing at run time.

use std::fmt;

use serde::Serialize;

/// A unit of axis position: the type of a position and its symbol.
pub trait Unit: Copy + PartialEq + PartialOrd + fmt::Debug + fmt::Display + Send + Sync + 'static {
    /// Symbol for messages, e.g. `mm`.
    const SYMBOL: &'static str;
    fn new(value: f64) -> Self;
    /// The number in this unit.
    fn value(self) -> f64;
}

macro_rules! unit {
    ($(#[$doc:meta])* $name:ident, $symbol:literal) => {
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq, PartialOrd, Default, Serialize)]
        pub struct $name(pub f64);

        impl Unit for $name {
            const SYMBOL: &'static str = $symbol;
            fn new(value: f64) -> Self {
                Self(value)
            }
            fn value(self) -> f64 {
                self.0
            }
        }

        /// The number (honouring the formatter's precision), then the symbol.
        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                fmt::Display::fmt(&self.0, f)?;
                write!(f, " {}", $symbol)
            }
        }

        impl From<$name> for f64 {
            fn from(x: $name) -> f64 {
                x.0
            }
        }
    };
}

unit!(
    /// Millimetres: the position of a linear stage.
    Mm,
    "mm"
);
unit!(
    /// Degrees: the angle of a rotation mount.
    Deg,
    "deg"
);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_print_with_their_symbol_and_give_their_number_back() {
        assert_eq!(format!("{:.3}", Mm(1.5)), "1.500 mm");
        assert_eq!(Deg(-30.0).to_string(), "-30 deg");
        assert_eq!(Mm::new(2.5).value(), 2.5);
        assert_eq!(f64::from(Deg(4.0)), 4.0);
        assert!(Mm(1.0) < Mm(2.0));
    }
}
