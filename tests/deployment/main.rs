//! The server as it is deployed, in one test binary (one link of the server for all of
//! them, and one run's worth of waiting for servers, clusters and sidecars shared): TLS
//! (`tls`), PostgreSQL as the store (`postgres`), recovery after a kill (`recovery`), a fleet
//! of servers on one database (`fleet`), the Agones lifecycle (`agones`) and the Kubernetes
//! manifests (`kubernetes`).

mod agones;
mod fleet;
mod kubernetes;
mod postgres;
mod recovery;
mod tls;
