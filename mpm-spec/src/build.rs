//! The build of a solver binary: its optimisation level.

use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// Optimisation level of a solver build, `o` + Cargo's `opt-level`. The paper's protocol
/// uses two: `o3` (profile `o3`) and `o0` (profile `o0`, "no optimisation").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OptLevel {
    /// `opt-level = 3` (profile `o3`).
    #[default]
    O3,
    /// `opt-level = 0`, debug assertions and overflow checks off (profile `o0`).
    O0,
    /// `opt-level = 1` (e.g. the dev profile).
    O1,
    /// `opt-level = 2`.
    O2,
    /// `opt-level = "s"`.
    Os,
    /// `opt-level = "z"`.
    Oz,
}

impl OptLevel {
    /// Every level.
    pub const ALL: [OptLevel; 6] = [OptLevel::O3, OptLevel::O0, OptLevel::O1, OptLevel::O2, OptLevel::Os, OptLevel::Oz];

    /// Its name (`o3`, `o0`, ...), also the Cargo profile of the two protocol levels.
    pub fn as_str(self) -> &'static str {
        match self {
            OptLevel::O3 => "o3",
            OptLevel::O0 => "o0",
            OptLevel::O1 => "o1",
            OptLevel::O2 => "o2",
            OptLevel::Os => "os",
            OptLevel::Oz => "oz",
        }
    }

    /// From Cargo's `opt-level` value (`3`, `0`, `s`, ...).
    pub fn of_cargo(level: &str) -> Option<Self> {
        format!("o{level}").parse().ok()
    }

    /// Whether the workspace has a Cargo profile of this name (the harness builds `o3` and
    /// `o0` only).
    pub fn has_profile(self) -> bool {
        matches!(self, OptLevel::O3 | OptLevel::O0)
    }
}

impl fmt::Display for OptLevel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for OptLevel {
    type Err = String;
    /// `o3`, `o0` (aliases `3`, `0`, `none`, `noopt`), `o1`, `o2`, `os`, `oz`.
    fn from_str(s: &str) -> Result<Self, String> {
        let s = s.trim().to_ascii_lowercase();
        let s = match s.as_str() {
            "3" => "o3",
            "0" | "none" | "noopt" => "o0",
            other => other,
        };
        Self::ALL
            .into_iter()
            .find(|o| o.as_str() == s)
            .ok_or_else(|| format!("unknown optimisation level '{s}' (known: o3, o0)"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_back() {
        for o in OptLevel::ALL {
            assert_eq!(o.as_str().parse::<OptLevel>(), Ok(o));
            assert_eq!(serde_json::to_value(o).unwrap(), o.as_str());
        }
        assert_eq!(OptLevel::of_cargo("3"), Some(OptLevel::O3));
        assert_eq!(OptLevel::of_cargo("s"), Some(OptLevel::Os));
        assert_eq!("noopt".parse::<OptLevel>(), Ok(OptLevel::O0));
        assert!("o4".parse::<OptLevel>().is_err());
    }
}
