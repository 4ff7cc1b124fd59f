//! The stroke case through the real server, as a client drives it: a session on the trainee's
//! scene `stroke_m1_thrombectomy` (the guide already in the cervical ICA, the distal-access
//! catheter, microcatheter and microwire inside it), the scene's operator demonstrating the
//! crossing of the left M1 clot; the distal-access catheter brought up, the microwire
//! exchanged for the stent retriever, the stent deployed (the bypass shows in the eTICI),
//! retrieved, a final DSA run; the session's metrics carry the passes, the first-pass effect,
//! the time to reperfusion and eTICI 3. (The femoral access before it is the engine's
//! `tests/scenes/case.rs` and the scene check `tests/scenes/every_scene.rs`: the
//! same operator in the same world, without half a minute of access in real time here.)

use std::time::{Duration, Instant};

use cathlab_api::pb;
use cathlab_api::pb::simulator_client::SimulatorClient;
use cathlab_tests::*;
use tonic::transport::Channel;

struct Driver {
    client: SimulatorClient<Channel>,
    session: pb::CreateSessionResponse,
    seq: u64,
}

impl Driver {
    async fn send(&mut self, kind: pb::command::Kind, instrument: Option<u32>) -> pb::CommandAck {
        self.try_send(kind, instrument).await.unwrap()
    }

    async fn try_send(
        &mut self,
        kind: pb::command::Kind,
        instrument: Option<u32>,
    ) -> Result<pb::CommandAck, tonic::Status> {
        self.seq += 1;
        let mut c = command(kind).unwrap();
        c.instrument = instrument;
        send(&mut self.client, &self.session, self.seq, Some(c)).await
    }

    async fn thrombectomy(&mut self, action: pb::ThrombectomyAction) -> pb::CommandAck {
        self.send(pb::command::Kind::Thrombectomy(action as i32), None)
            .await
    }

    async fn target(&mut self, instrument: u32, mm: f64) {
        self.send(
            pb::command::Kind::Insertion(pb::Insertion {
                mode: Some(pb::insertion::Mode::TargetMm(mm)),
                hold: false,
            }),
            Some(instrument),
        )
        .await;
    }

    async fn metrics(&mut self) -> pb::Metrics {
        self.client
            .get_session(authed(
                pb::GetSessionRequest {
                    session_id: self.session.session_id.clone(),
                },
                INSTRUCTOR_KEY,
            ))
            .await
            .unwrap()
            .into_inner()
            .metrics
            .unwrap()
    }

    /// Polls the metrics until `done` (at most `seconds`).
    async fn until(&mut self, seconds: u64, what: &str, done: impl Fn(&pb::Metrics) -> bool) {
        let deadline = Instant::now() + Duration::from_secs(seconds);
        loop {
            let m = self.metrics().await;
            if done(&m) {
                return;
            }
            assert!(
                Instant::now() < deadline,
                "{what} within {seconds} s: {m:?}"
            );
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    }

    /// Reads states until `done` (at most `seconds`).
    async fn until_state(
        &mut self,
        seconds: u64,
        what: &str,
        done: impl Fn(&pb::DeviceState) -> bool,
    ) -> pb::DeviceState {
        let mut stream = self
            .client
            .stream_state(authed(
                pb::StreamStateRequest {
                    session_id: self.session.session_id.clone(),
                    tip_only: false,
                },
                &self.session.observer_token,
            ))
            .await
            .unwrap()
            .into_inner();
        let deadline = Instant::now() + Duration::from_secs(seconds);
        loop {
            let s = stream.message().await.unwrap().unwrap();
            if done(&s) {
                return s;
            }
            assert!(Instant::now() < deadline, "{what} within {seconds} s");
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn thrombectomy_through_the_server_from_the_clot_crossing_to_etici_3() {
    let dir = temp_dir("thrombectomy");
    // The procedure at the scene's fidelity: the overload governor's level changes are wall
    // clock timed, and once (in a CI run, levels 1 to 3 during the distal-access catheter's
    // advance) the four-instrument stack diverged and was put back at its start.
    let server = ServerProcess::start(&dir.join("cathlab.sqlite"), &["--no-overload-governor"]);
    let mut client = server.client().await;
    let session = client
        .create_session(pb::CreateSessionRequest {
            scene: Some(pb::create_session_request::Scene::SceneName(
                "stroke_m1_thrombectomy".into(),
            )),
            label: "thrombectomy".into(),
            ..Default::default()
        })
        .await
        .expect("the stroke scene starts")
        .into_inner();
    let mut d = Driver {
        client,
        session,
        seq: 0,
    };
    d.until(60, "the occlusion graded", |m| {
        m.reperfusion.as_ref().is_some_and(|r| r.etici == "0") && m.thrombectomy.is_some()
    })
    .await;
    // Stent commands before a stent retriever is in: refused, saying why.
    let err = d
        .try_send(
            pb::command::Kind::Thrombectomy(pb::ThrombectomyAction::DeployStent as i32),
            None,
        )
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::FailedPrecondition);
    assert!(
        err.message().contains("stent retriever"),
        "{}",
        err.message()
    );
    // The stack in the ICA: guide, distal-access catheter, microcatheter, microwire.
    let start = d
        .until_state(30, "the stack", |s| s.instruments.len() == 4)
        .await;
    let ids = |s: &pb::DeviceState| -> Vec<String> {
        s.instruments
            .iter()
            .map(|i| i.catalogue_id.clone())
            .collect()
    };
    let stack = [
        "guide-6f-071-90",
        "distal-access-058-115",
        "microcatheter-021-160",
        "microwire-014-angled",
    ];
    assert_eq!(ids(&start), stack);
    // The scene's operator crosses the clot: the microcatheter beyond it.
    d.send(pb::command::Kind::Demonstrate(true), None).await;
    d.until(120, "the microcatheter across the clot", |m| {
        m.target_reached
    })
    .await;
    let crossed = d
        .until_state(30, "every hand still", |s| {
            s.instruments.len() == 4 && s.instruments.iter().all(|i| i.inserted_mm.is_finite())
        })
        .await;
    assert_eq!(ids(&crossed), stack);
    // The guide stays where the scene put it.
    assert!(
        (crossed.instruments[0].inserted_mm - start.instruments[0].inserted_mm).abs() < 2.0,
        "{} → {}",
        start.instruments[0].inserted_mm,
        crossed.instruments[0].inserted_mm
    );
    let micro = crossed.instruments[2].inserted_mm;
    let m = d.metrics().await;
    let t = m.thrombectomy.unwrap();
    assert!(
        t.crossing_force_n > 0.0 && t.peak_crossing_force_n > 0.0,
        "{t:?}"
    );
    // The distal-access catheter up to 8 mm short of the M1 (the microcatheter is 21 mm into
    // it).
    d.target(1, micro - 29.0).await;
    d.until_state(30, "the distal-access catheter up", |s| {
        (s.instruments[1].inserted_mm - (micro - 29.0)).abs() < 0.5
    })
    .await;
    // The microwire out, the stent retriever in.
    d.send(
        pb::command::Kind::Exchange(pb::Exchange {
            instrument: 3,
            device: Some(pb::exchange::Device::CatalogueId(
                "stent-retriever-4x20".into(),
            )),
        }),
        None,
    )
    .await;
    d.until_state(60, "the exchange", |s| {
        s.instruments[3].catalogue_id == "stent-retriever-4x20"
    })
    .await;
    d.target(3, micro).await;
    d.until_state(60, "the stent at the microcatheter's tip", |s| {
        (s.instruments[3].inserted_mm - micro).abs() < 0.3
    })
    .await;
    // Deployed: grip, and the bypass flow through the stent.
    d.thrombectomy(pb::ThrombectomyAction::DeployStent).await;
    d.until(60, "the stent open across the clot", |m| {
        m.thrombectomy.as_ref().is_some_and(|t| t.grip_n > 0.05)
            && m.reperfusion.as_ref().is_some_and(|r| r.fraction > 0.05)
    })
    .await;
    // Retrieved.
    d.thrombectomy(pb::ThrombectomyAction::RetrieveStent).await;
    d.until(60, "the pass", |m| {
        m.thrombectomy.as_ref().is_some_and(|t| t.passes > 0)
    })
    .await;
    // The final DSA run.
    d.send(pb::command::Kind::Dsa(true), None).await;
    d.send(
        pb::command::Kind::Inject(pb::Injection {
            volume_ml: 6.0,
            rate_ml_s: 4.0,
        }),
        None,
    )
    .await;
    tokio::time::sleep(Duration::from_secs(2)).await;
    d.send(pb::command::Kind::Dsa(false), None).await;
    let m = d.metrics().await;
    let t = m.thrombectomy.unwrap();
    assert_eq!(t.passes, 1, "{t:?}");
    assert!(t.first_pass_effect, "{t:?}");
    assert_eq!(t.emboli, 0);
    let r = m.reperfusion.unwrap();
    assert_eq!(r.etici, "3", "{r:?}");
    assert!(t.reperfused_at_s.unwrap() <= m.procedure_time_s);
    assert!(m.dsa_runs >= 1);
    close(&mut d.client, &d.session).await;
}
