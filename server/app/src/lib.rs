//! The cathlab server: configuration, the SQLite store, the Simulator service and the
//! assembly of everything into one listening server (`cathlab-server`).

pub mod agones;
pub mod auth;
pub mod config;
pub mod connections;
pub mod fleet;
pub mod heap;
pub mod intake;
pub mod replays;
pub mod reports;
pub mod server;
pub mod service;
pub mod store;
pub mod streams;
