//! What a random client may do ([`Action`]), how often, and how many times a round.

/// What a random client may do, and how often (relative weights).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum Action {
    Create,
    Close,
    ValidCommand,
    InvalidCommand,
    Frames,
    Control,
    Watch,
    Query,
    HostileScene,
    Garbage,
    Replay,
    /// An HTTP/2 connection opening up to 100 streams, each a message begun and stalled.
    H2Flood,
    /// HTTP/1.1 gRPC-Web requests whose bodies stop part-way.
    StalledBody,
    /// Requests (HTTP/1.1 and HTTP/2) whose bodies never start.
    BodyNeverStarts,
    /// Sockets that never send a byte.
    IdleSockets,
    /// Inline scenes whose CT is a decompression bomb or a header declaring too many voxels.
    BombFile,
}

impl Action {
    pub(crate) const ALL: [Action; 16] = [
        Action::Create,
        Action::Close,
        Action::ValidCommand,
        Action::InvalidCommand,
        Action::Frames,
        Action::Control,
        Action::Watch,
        Action::Query,
        Action::HostileScene,
        Action::Garbage,
        Action::Replay,
        Action::H2Flood,
        Action::StalledBody,
        Action::BodyNeverStarts,
        Action::IdleSockets,
        Action::BombFile,
    ];

    pub(crate) fn weight(self) -> u32 {
        match self {
            Action::Create => 8,
            Action::Close => 3,
            Action::ValidCommand => 30,
            Action::InvalidCommand => 15,
            Action::Frames => 10,
            Action::Control => 8,
            Action::Watch => 8,
            Action::Query => 8,
            Action::HostileScene => 5,
            Action::Garbage => 3,
            Action::Replay => 2,
            Action::H2Flood => 3,
            Action::StalledBody => 3,
            Action::BodyNeverStarts => 2,
            Action::IdleSockets => 3,
            Action::BombFile => 4,
        }
    }

    /// How many times one client may start it in a round (the connection attacks run in
    /// tasks of their own, each bounded in time; these bound how many sockets they hold).
    pub(crate) fn per_round(self) -> u32 {
        match self {
            Action::H2Flood | Action::BodyNeverStarts => 2,
            Action::StalledBody | Action::IdleSockets => 3,
            Action::BombFile => 6,
            _ => u32::MAX,
        }
    }
}
