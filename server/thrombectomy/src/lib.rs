//! Stroke thrombectomy mechanics: the clot by composition ([`clot`]), the stent retriever's
//! radial force law and unsheathed shape ([`stent`]), the way back to the catheter
//! ([`path`]), the force balances of stent-retriever and aspiration passes with their emboli
//! ([`retrieval`]) and the seeded outcome sweep ([`sweep`]). A plain synchronous library:
//! no threads, no clock, seeds passed in. Every parameter's source is in its module's doc.

pub mod clot;
pub mod error;
pub mod path;
pub mod retrieval;
pub mod stent;
pub mod sweep;

pub use clot::{Clot, ClotComposition, ClotMechanics};
pub use error::{Result, ThrombectomyError};
pub use path::RetrievalPath;
pub use retrieval::{
    AspirationPass, AspirationSetup, DEFAULT_SUCTION_PA, Engagement, PassOutcome, StentPass,
    StentSetup, drag_n,
};
pub use stent::{Deployment, StentRetriever, Surroundings, cerebral_wall_stiffness};
