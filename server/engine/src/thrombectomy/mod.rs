//! The thrombectomy of a clotted scene, step by step: where each clot sits on the route,
//! what crossing it took, the stent retriever unsheathed across it (engagement, bypass flow),
//! retrieval and aspiration passes driven by the hands, emboli lodged downstream, and the
//! clots the flow must carry. The mechanics are `cathlab-thrombectomy`'s; this module maps
//! instruments on the route to its passes.
//!
//! `procedure` holds the procedure's state and its step; `passes` the crossings, passes and
//! emboli that step drives; `route` distances along the route; `script` the stroke case's
//! scripted operator (for tests and the benchmark), which drives a whole world.

mod passes;
mod procedure;
mod route;
mod script;
#[cfg(test)]
mod tests;

pub use procedure::{
    InstrumentView, Procedure, ProcedureFigures, ProcedureStep, SCENE_WEDGE_STRAIN,
};
pub use route::route_arc;
pub use script::StrokeScript;
