//! One random client ([`Chaos`]): its connection, its session and sequence numbers, what it
//! may do and how often it did each this round; the target of its calls and its random picks.

use std::collections::BTreeMap;
use std::sync::Arc;

use anyhow::Result;
use cathlab_api::pb;
use cathlab_api::pb::simulator_client::SimulatorClient;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use tonic::transport::Channel;

use crate::actions::Action;
use crate::bombs::Bombs;
use crate::common::KEY;
use crate::tally::Tally;

/// One random client: its connection, its session, its sequence numbers.
pub(crate) struct Chaos {
    pub(crate) rng: StdRng,
    pub(crate) url: String,
    pub(crate) address: String,
    pub(crate) client: SimulatorClient<Channel>,
    pub(crate) session: Option<pb::CreateSessionResponse>,
    pub(crate) seq: u64,
    pub(crate) tally: Arc<Tally>,
    /// Streams left stalled, dropped by their own tasks.
    pub(crate) stalls: Vec<tokio::task::JoinHandle<()>>,
    /// What it may do (never empty).
    pub(crate) actions: Vec<Action>,
    /// The bomb scenes.
    pub(crate) bombs: Arc<Bombs>,
    /// How many times each action was started this round.
    pub(crate) started: BTreeMap<&'static str, u32>,
}

impl Chaos {
    pub(crate) async fn new(
        url: String,
        address: String,
        seed: u64,
        tally: Arc<Tally>,
        actions: Vec<Action>,
        bombs: Arc<Bombs>,
    ) -> Result<Self> {
        let client = SimulatorClient::connect(url.clone())
            .await?
            .max_decoding_message_size(64 << 20);
        Ok(Self {
            rng: StdRng::seed_from_u64(seed),
            url,
            address,
            client,
            session: None,
            seq: 0,
            tally,
            stalls: Vec::new(),
            actions,
            bombs,
            started: BTreeMap::new(),
        })
    }

    /// Whether `action` may start again this round (and counts it).
    pub(crate) fn budget(&mut self, action: Action) -> bool {
        let name: &'static str = match action {
            Action::H2Flood => "h2 flood",
            Action::StalledBody => "stalled body",
            Action::BodyNeverStarts => "body never starts",
            Action::IdleSockets => "idle socket",
            Action::BombFile => "bomb file",
            _ => return true,
        };
        let n = self.started.entry(name).or_default();
        *n += 1;
        *n <= action.per_round()
    }

    pub(crate) fn pick<T: Clone>(&mut self, items: &[T]) -> T {
        items[self.rng.random_range(0..items.len())].clone()
    }

    /// A session id and token: this client's, or (rarely) a wrong one.
    pub(crate) fn target(&mut self) -> (String, String) {
        let own = self
            .session
            .as_ref()
            .map(|s| (s.session_id.clone(), s.controller_token.clone()));
        match (own, self.rng.random_range(0..20)) {
            (Some((id, _)), 0) => (id, "not-a-token".into()),
            (_, 1) => ("no-such-session".into(), "not-a-token".into()),
            (Some(own), _) => own,
            (None, _) => ("no-such-session".into(), KEY.into()),
        }
    }
}
