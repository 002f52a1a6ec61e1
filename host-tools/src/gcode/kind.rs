//! What kind of fault a diagnostic reports, set where the error is raised, so that a
//! caller can act on it without reading the words of its message (the Grbl bridge
//! turns it into Grbl 1.1's `error:N`).

/// Declares [`ErrorKind`] and the list of all its kinds, [`ErrorKind::ALL`].
macro_rules! kinds {
    ($($(#[doc = $doc:literal])* $name:ident,)*) => {
        /// The kind of a front-end error.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        pub enum ErrorKind {
            $($(#[doc = $doc])* $name,)*
        }

        impl ErrorKind {
            /// Every kind, in declaration order.
            pub const ALL: &'static [ErrorKind] = &[$(ErrorKind::$name,)*];
        }
    };
}

kinds! {
    /// Something other than a word's letter where a word should begin (a stray
    /// character, a control character).
    ExpectedLetter,
    /// The line is not well-formed around its words: a comment left open or nested, a
    /// checksum that is malformed or wrong, a parameter setting without `=`, an O-word
    /// not at the start of its line.
    Syntax,
    /// A value that cannot be read or computed: a malformed number, a word without its
    /// value, a bracketed expression that is malformed or fails (division by zero, a
    /// function outside its domain, an unknown function).
    BadNumber,
    /// A value beyond what can be held or used (a feed, speed, dwell or rotation too
    /// large or too small, a number with too many digits).
    OutOfRange,
    /// A parameter read before it was set, a parameter number out of range, or a
    /// setting the parameter does not take (read-only, out of its range).
    Parameter,
    /// A negative (or zero) value where a positive one is needed: a feed, a dwell, a
    /// peck depth, a tolerance, a tool number or radius.
    Negative,
    /// A legal feature of the dialect that is not implemented (the message starts
    /// with [`super::UNSUPPORTED`]).
    Unsupported,
    /// A G or M code, a word letter or an O-word keyword that the dialect does not
    /// have.
    UnknownCode,
    /// An axis word for an axis the machine does not have.
    NoSuchAxis,
    /// A code or word that the dialect does not take in the mode in force (cutter
    /// compensation on, a plane other than XY, inverse-time feed, incremental
    /// distance for G53, a word that may not go with it).
    ModeConflict,
    /// O-word flow control that does not match up, or O-words where only plain lines
    /// run (line by line).
    Flow,
    /// Two codes of one modal group on a line.
    ModalGroup,
    /// A feed move without a feed rate (none set, or F0).
    NoFeed,
    /// A value that must be a whole number is not.
    NotInteger,
    /// Two commands on one line that would both use the axis words.
    TwoAxisCommands,
    /// A word given twice on one line.
    RepeatedWord,
    /// A command that needs axis words has none.
    NoAxisWords,
    /// A command is missing a value word it needs (G4's P, a canned cycle's R …).
    MissingValue,
    /// G53 without G0 or G1.
    G53Motion,
    /// Axis words that no command on the line and no mode in force uses.
    UnusedAxisWords,
    /// An arc without an axis word in its plane where one is needed.
    ArcNoPlaneAxis,
    /// A motion whose target or path cannot be made: a position out of range, an
    /// arc's end off its circle, a curve too large, a cutter-compensated path that
    /// does not fit.
    InvalidTarget,
    /// An arc radius that cannot reach the end point (or R0).
    ArcRadius,
    /// An arc with neither a centre (I J K) nor a radius (R).
    ArcNoOffset,
    /// Value words that no command on the line uses.
    UnusedWords,
    /// A tool number the tool table does not hold.
    ToolNumber,
    /// A line longer than the front end reads.
    LineTooLong,
}
