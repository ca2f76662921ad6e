//! What a part is said to be: which face lies up, and why it was accepted or not. Below every
//! module that names them, so that none imports the estimator's own module for its words.

/// Which side of the part faces the camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Face {
    /// The face enrolled as "up" (FACE 1).
    Up,
    /// The other face (FACE 2).
    Down,
}

impl Face {
    /// "up" or "down", as the KB and the log spell it.
    pub fn as_str(self) -> &'static str {
        match self {
            Face::Up => "up",
            Face::Down => "down",
        }
    }
    /// Register encoding: 1 up, 2 down (0 is "unknown").
    pub fn code(self) -> u16 {
        match self {
            Face::Up => 1,
            Face::Down => 2,
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

/// Why a part was not accepted. The numeric codes are the register map's REASON values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Reason {
    /// Accepted (0).
    Ok,
    /// No part in the frame: the one result of an empty belt (1).
    NoPart,
    /// No template fits well enough (2).
    UnknownType,
    /// The line features agree less than the threshold (3).
    LowConfidence,
    /// Another type or face fits nearly as well (4).
    Ambiguous,
    /// Touching or overlapping parts that cannot be told apart (5).
    Touching,
    /// Not the EXPECTED_TYPE the PLC asked for (6).
    WrongType,
    /// No usable frame: the result of a camera or frame fault (7).
    FrameError,
    /// Cut by the frame's edge (8).
    AtBorder,
    /// Another part lies partly on this one: grasping it would drag the one on top.
    Covered,
    /// The gripper's keep-out footprint around the part holds other material.
    NoClearance,
}

impl Reason {
    /// Every reason, in code order.
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
    /// The REASON register's value.
    pub fn code(self) -> u16 {
        self as u16
    }
    /// The reason as the log and the page write it.
    pub fn as_str(self) -> &'static str {
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
