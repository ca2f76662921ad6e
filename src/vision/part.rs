//! What a part is said to be: which face lies up, and why it was accepted or not. Below every
//! module that names them, so that none imports the estimator's own module for its words.

/// Which side of the part faces the camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Face {
    /// The face enrolled as "up".
    Up,
    /// The other face.
    Down,
}

impl Face {
    /// "up" or "down", as the KB and the log spell it.
    pub const fn as_str(self) -> &'static str {
        match self {
            Face::Up => "up",
            Face::Down => "down",
        }
    }
}

impl std::str::FromStr for Face {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "up" => Ok(Face::Up),
            "down" => Ok(Face::Down),
            other => Err(format!("face must be \"up\" or \"down\", not {other:?}")),
        }
    }
}

impl std::fmt::Display for Face {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Why a part was not accepted. Its number on the wire (REASON) is `registers`' business, not
/// the estimator's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Reason {
    /// Accepted.
    Ok,
    /// No part in the frame: the one result of an empty belt.
    NoPart,
    /// No template fits well enough.
    UnknownType,
    /// The line features agree less than the threshold.
    LowConfidence,
    /// Another type or face fits nearly as well.
    Ambiguous,
    /// Touching or overlapping parts that cannot be told apart.
    Touching,
    /// Not the EXPECTED_TYPE the PLC asked for.
    WrongType,
    /// No usable frame: the result of a camera or frame fault.
    FrameError,
    /// Cut by the frame's edge.
    AtBorder,
    /// Another part lies partly on this one: grasping it would drag the one on top.
    Covered,
    /// The gripper's keep-out footprint around the part holds other material.
    NoClearance,
}

impl Reason {
    /// Every reason, each once (counters are indexed by [`Reason::index`]).
    pub const ALL: [Reason; 11] = [
        Reason::Ok,
        Reason::NoPart,
        Reason::UnknownType,
        Reason::LowConfidence,
        Reason::Ambiguous,
        Reason::Touching,
        Reason::WrongType,
        Reason::FrameError,
        Reason::AtBorder,
        Reason::Covered,
        Reason::NoClearance,
    ];
    /// Its position in [`Reason::ALL`]: a counter's slot.
    pub fn index(self) -> usize {
        self as usize
    }
    /// The reason as the log and the page write it.
    pub const fn as_str(self) -> &'static str {
        match self {
            Reason::Ok => "ok",
            Reason::NoPart => "no part",
            Reason::UnknownType => "unknown type",
            Reason::LowConfidence => "low confidence",
            Reason::Ambiguous => "ambiguous",
            Reason::Touching => "touching/overlapping",
            Reason::WrongType => "wrong type",
            Reason::FrameError => "frame error",
            Reason::AtBorder => "at the image border",
            Reason::Covered => "covered",
            Reason::NoClearance => "no clearance",
        }
    }
}

impl std::fmt::Display for Reason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}
