//! The store's tests: the same checks on SQLite and on a throwaway PostgreSQL cluster, a
//! database that cannot be reached, and old databases migrated (a newer one refused).

use super::*;
use cathlab_engine::Metrics;
use cathlab_engine::world::Command;

fn sqlite(name: &str) -> StoreLocation {
    let dir = std::env::temp_dir().join(format!("cathlab-store-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join(format!("{name}.sqlite"));
    let _ = std::fs::remove_file(&file);
    StoreLocation::Sqlite(file)
}

/// A connection beside the store's, to write what the store would not.
fn raw(location: &StoreLocation) -> Box<dyn Conn> {
    match location {
        StoreLocation::Sqlite(file) => Box::new(SqliteConn::open(file).unwrap()),
        StoreLocation::Postgres(url) => Box::new(PgTarget::parse(url).unwrap().connect().unwrap()),
    }
}

fn session(id: &str, status: &str) -> StoredSession {
    StoredSession {
        id: id.into(),
        label: String::new(),
        scene_name: "scene".into(),
        scene_json: "{}".into(),
        base_dir: PathBuf::from("."),
        created_unix_s: 0.0,
        status: status.into(),
        step_rate_hz: 500.0,
        account_id: None,
        controller_hash: None,
        server_id: None,
    }
}

fn the_governors_commands_are_replayed_but_not_counted(location: &StoreLocation) {
    let store = Store::at(location).unwrap();
    let commands = [
        Command::PushVelocity(0.1),
        Command::Fidelity(2),
        Command::TwistRate(1.0),
        Command::Fidelity(1),
    ];
    for (ordinal, command) in commands.iter().enumerate() {
        let record = CommandRecord {
            ordinal: ordinal as u64,
            step: 10 * ordinal as u64,
            seq: 1,
            command: *command,
        };
        Recorder::command(&store, "s1", record, None);
    }
    store.flush();
    assert_eq!(store.command_count("s1").unwrap(), 2);
    let stored: Vec<Command> = store
        .commands("s1")
        .unwrap()
        .into_iter()
        .map(|c| c.command)
        .collect();
    assert_eq!(stored, commands);
}

fn corrupt_rows_are_named(location: &StoreLocation) {
    let store = Store::at(location).unwrap();
    store.insert_session(session("s1", "running")).unwrap();
    let mut conn = raw(location);
    conn.execute(
        "INSERT INTO commands VALUES ('s1', 0, 5, 1, '{\"no_such_command\": 1}')",
        &[],
    )
    .unwrap();
    conn.execute(
        "INSERT INTO checkpoints VALUES ('s1', 500, 'not-hex', '{}')",
        &[],
    )
    .unwrap();
    let command = store.commands("s1").unwrap_err().to_string();
    assert!(
        command.contains("corrupt command 0 of session s1"),
        "{command}"
    );
    let checkpoint = store.checkpoints("s1").unwrap_err().to_string();
    assert!(checkpoint.contains("digest at step 500"), "{checkpoint}");
    assert_eq!(store.command_count("s1").unwrap(), 1);
    // A store opened again marks the running session interrupted.
    drop(store);
    let store = Store::at(location).unwrap();
    assert_eq!(store.session("s1").unwrap().unwrap().status, "interrupted");
    assert!(store.session("s2").unwrap().is_none());
}

fn stored_numbers_come_back_bit_for_bit(location: &StoreLocation) {
    // Regression: serde_json's default parser read 0.012097896199016495 back one unit in
    // the last place off (a stored score differed from the report's; a stored command
    // could replay differently).
    let store = Store::at(location).unwrap();
    let awkward = [
        0.012097896199016495,
        0.1 + 0.2,
        1.0 / 3.0,
        2.2250738585072014e-308,
    ];
    for (ordinal, v) in awkward.iter().enumerate() {
        let record = CommandRecord {
            ordinal: ordinal as u64,
            step: ordinal as u64,
            seq: 1,
            command: Command::PushVelocity(*v),
        };
        Recorder::command(&store, "s1", record, None);
    }
    store.flush();
    let back: Vec<u64> = store
        .commands("s1")
        .unwrap()
        .iter()
        .map(|c| match c.command {
            Command::PushVelocity(v) => v.to_bits(),
            _ => 0,
        })
        .collect();
    let sent: Vec<u64> = awkward.iter().map(|v| v.to_bits()).collect();
    assert_eq!(back, sent);
    // A session's numbers too (a double column, not a single-precision one).
    let mut s = session("s2", "closed");
    s.created_unix_s = 1_790_000_000.123_456_7;
    s.step_rate_hz = 1.0 / 3.0;
    store.insert_session(s.clone()).unwrap();
    assert_eq!(store.session("s2").unwrap().unwrap(), s);
}

fn a_batch_keeps_its_order_and_a_failed_batch_acknowledges_nothing(location: &StoreLocation) {
    let store = Store::at(location).unwrap();
    store.insert_session(session("s1", "running")).unwrap();
    let mut acks = Vec::new();
    for ordinal in 0..1500u64 {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let record = CommandRecord {
            ordinal,
            step: ordinal,
            seq: ordinal,
            command: Command::PushVelocity(ordinal as f64 * 1e-3),
        };
        Recorder::command(&store, "s1", record, Some(tx));
        acks.push(rx);
    }
    store.event(
        "s1",
        &Event {
            step: 1,
            time_s: 0.002,
            kind: cathlab_engine::EventKind::Device,
            message: "first".into(),
        },
    );
    store.event(
        "s1",
        &Event {
            step: 1,
            time_s: 0.002,
            kind: cathlab_engine::EventKind::Device,
            message: "second".into(),
        },
    );
    store.set_status("s1", "closed");
    store.flush();
    for (i, ack) in acks.into_iter().enumerate() {
        assert_eq!(ack.blocking_recv().unwrap().unwrap().ordinal, i as u64);
    }
    let ordinals: Vec<u64> = store
        .commands("s1")
        .unwrap()
        .iter()
        .map(|c| c.ordinal)
        .collect();
    assert_eq!(ordinals, (0..1500).collect::<Vec<_>>());
    let events: Vec<String> = store
        .events("s1")
        .unwrap()
        .into_iter()
        .map(|e| e.3)
        .collect();
    assert_eq!(events, ["first", "second"]);
    assert_eq!(store.session("s1").unwrap().unwrap().status, "closed");
    // A command whose ordinal is already stored fails its batch (whichever other writes
    // share it): an acknowledgement says stored exactly when the command is.
    let (tx, rx) = tokio::sync::oneshot::channel();
    let (tx2, rx2) = tokio::sync::oneshot::channel();
    for (ordinal, tx) in [(1500, tx), (7, tx2)] {
        let record = CommandRecord {
            ordinal,
            step: ordinal,
            seq: 1,
            command: Command::PushVelocity(0.5),
        };
        Recorder::command(&store, "s1", record, Some(tx));
    }
    store.flush();
    let (fresh, duplicate) = (rx.blocking_recv().unwrap(), rx2.blocking_recv().unwrap());
    assert!(duplicate.is_err(), "{duplicate:?}");
    let stored = store.commands("s1").unwrap();
    assert_eq!(
        fresh.is_ok(),
        stored.iter().any(|c| c.ordinal == 1500),
        "{fresh:?}"
    );
    assert_eq!(stored[7].command, Command::PushVelocity(0.007));
}

/// Two servers on one store: each marks only its own sessions interrupted at start; a
/// silent server is marked lost by the other's clock check, with its running sessions;
/// its heartbeat brings them back; another process under its id finds them interrupted.
fn the_fleet_registry_keeps_servers_and_their_sessions_apart(location: &StoreLocation) {
    let a = Store::for_server(location, "a").unwrap();
    let b = Store::for_server(location, "b").unwrap();
    let on = |id: &str, server: &str| StoredSession {
        server_id: Some(server.into()),
        ..session(id, "running")
    };
    a.insert_session(on("a1", "a")).unwrap();
    b.insert_session(on("b1", "b")).unwrap();
    b.insert_session(on("b2", "b")).unwrap();
    a.heartbeat("http://a:1", 4, 1).unwrap();
    b.heartbeat("http://b:1", 4, 2).unwrap();
    let servers = a.servers().unwrap();
    assert_eq!(
        servers
            .iter()
            .map(|s| (s.id.as_str(), s.address.as_str(), s.load, s.status.as_str()))
            .collect::<Vec<_>>(),
        [
            ("a", "http://a:1", 1, "serving"),
            ("b", "http://b:1", 2, "serving")
        ]
    );
    assert!(servers[0].heartbeat_unix_s >= servers[0].started_unix_s);
    let elsewhere = |s: &Store| -> Vec<String> {
        s.running_elsewhere()
            .unwrap()
            .into_iter()
            .map(|s| s.id)
            .collect::<Vec<_>>()
    };
    assert_eq!(elsewhere(&a).len(), 2);
    assert_eq!(elsewhere(&b), ["a1"]);
    // Nobody is silent for an hour: nothing lost.
    a.mark_lost(3600.0).unwrap();
    assert_eq!(b.session("b1").unwrap().unwrap().status, "running");
    // Everyone is "silent" for a negative time: both lost, with their sessions.
    a.mark_lost(-1.0).unwrap();
    assert_eq!(b.session("b1").unwrap().unwrap().status, "lost");
    assert_eq!(a.session("a1").unwrap().unwrap().status, "lost");
    assert!(a.servers().unwrap().iter().all(|s| s.status == "lost"));
    // A's heartbeat: a serves again, its session runs again; b's stay lost.
    a.heartbeat("http://a:1", 4, 1).unwrap();
    assert_eq!(a.session("a1").unwrap().unwrap().status, "running");
    assert_eq!(a.session("b2").unwrap().unwrap().status, "lost");
    // A new process as b: its lost sessions were interrupted; a's untouched.
    drop(b);
    let b = Store::for_server(location, "b").unwrap();
    assert_eq!(b.session("b1").unwrap().unwrap().status, "interrupted");
    assert_eq!(b.session("a1").unwrap().unwrap().status, "running");
    b.heartbeat("http://b:2", 4, 0).unwrap();
    assert_eq!(b.session("b2").unwrap().unwrap().status, "interrupted");
    // A clean stop.
    a.unregister().unwrap();
    let a_row = b
        .servers()
        .unwrap()
        .into_iter()
        .find(|s| s.id == "a")
        .unwrap();
    assert_eq!((a_row.status.as_str(), a_row.load), ("stopped", 0));
}

fn check_all(location: impl Fn(&str) -> StoreLocation) {
    the_fleet_registry_keeps_servers_and_their_sessions_apart(&location("fleet"));
    the_governors_commands_are_replayed_but_not_counted(&location("governor"));
    corrupt_rows_are_named(&location("corrupt"));
    stored_numbers_come_back_bit_for_bit(&location("bits"));
    a_batch_keeps_its_order_and_a_failed_batch_acknowledges_nothing(&location("batch"));
}

#[test]
fn the_sqlite_store_records_and_reads_back() {
    check_all(sqlite);
}

#[test]
fn the_postgres_store_records_and_reads_back_as_the_sqlite_one() {
    let cluster = cluster::PgCluster::start().unwrap();
    check_all(|name| StoreLocation::Postgres(cluster.database(name).unwrap()));
}

#[test]
fn an_unreachable_postgres_database_never_blocks_the_recorder_and_acknowledges_nothing() {
    let cluster = cluster::PgCluster::start().unwrap();
    let location = StoreLocation::Postgres(cluster.database("outage").unwrap());
    let store = Store::with_queue(&location, LOCAL_SERVER, 16).unwrap();
    assert!(store.is_reachable());
    cluster.stop();
    let mut acks = Vec::new();
    // Far more writes than the queue holds, as the physics threads would make them.
    for step in 0..20_000u64 {
        store.checkpoint(
            "s1",
            Checkpoint {
                step,
                digest: step,
                metrics: Metrics::default(),
            },
        );
        if step % 100 == 0 {
            let (tx, rx) = tokio::sync::oneshot::channel();
            let record = CommandRecord {
                ordinal: step / 100,
                step,
                seq: step / 100,
                command: Command::PushVelocity(0.0),
            };
            Recorder::command(&store, "s1", record, Some(tx));
            acks.push(rx);
        }
    }
    assert!(!store.is_reachable());
    assert!(store.refused_writes() > 0);
    for ack in acks {
        let answer = ack.blocking_recv().unwrap();
        assert!(
            answer.is_err(),
            "acknowledged while unreachable: {answer:?}"
        );
    }
    // Back again: written and acknowledged.
    cluster.restart().unwrap();
    let (tx, rx) = tokio::sync::oneshot::channel();
    let record = CommandRecord {
        ordinal: 1000,
        step: 1,
        seq: 1,
        command: Command::PushVelocity(0.0),
    };
    Recorder::command(&store, "s1", record, Some(tx));
    assert!(rx.blocking_recv().unwrap().is_ok());
    assert!(store.is_reachable());
    assert_eq!(store.commands("s1").unwrap().len(), 1);
}

#[test]
fn an_old_sqlite_database_is_migrated_and_keeps_its_sessions_and_a_newer_one_is_refused() {
    let location = sqlite("old");
    let StoreLocation::Sqlite(file) = &location else {
        unreachable!()
    };
    // As the first release left it: the first schema, user_version 0, one session.
    let mut conn = SqliteConn::open(file).unwrap();
    conn.batch(sqlite::SCHEMA_V1).unwrap();
    conn.execute(
        "INSERT INTO sessions VALUES ('s1', 'old', 'scene', '{}', '.', 1.0, 'closed', 500.0)",
        &[],
    )
    .unwrap();
    drop(conn);
    let version = || {
        SqliteConn::open(file)
            .unwrap()
            .query("PRAGMA user_version", &[])
            .unwrap()[0]
            .int(0)
            .unwrap()
    };
    migrated_then_refused(&location, &|| version() as usize, &|| {
        SqliteConn::open(file)
            .unwrap()
            .batch("PRAGMA user_version = 99")
            .unwrap()
    });
}

#[test]
fn an_old_postgres_database_is_migrated_and_keeps_its_sessions_and_a_newer_one_is_refused() {
    let cluster = cluster::PgCluster::start().unwrap();
    let location = StoreLocation::Postgres(cluster.database("old").unwrap());
    let raw = || {
        PgTarget::parse(&cluster.url("old"))
            .unwrap()
            .connect()
            .unwrap()
    };
    // A database at version 1, with one session.
    let mut conn = raw();
    conn.batch(&format!(
        "CREATE TABLE cathlab_schema (version BIGINT NOT NULL);
         INSERT INTO cathlab_schema VALUES (1); {}",
        postgres::MIGRATIONS[0]
    ))
    .unwrap();
    conn.execute(
        "INSERT INTO sessions VALUES ('s1', 'old', 'scene', '{}', '.', 1.0, 'closed', 500.0)",
        &[],
    )
    .unwrap();
    drop(conn);
    migrated_then_refused(
        &location,
        &|| {
            raw()
                .query("SELECT version FROM cathlab_schema", &[])
                .unwrap()[0]
                .int(0)
                .unwrap() as usize
        },
        &|| {
            raw()
                .batch("UPDATE cathlab_schema SET version = 99")
                .unwrap()
        },
    );
}

fn migrated_then_refused(
    location: &StoreLocation,
    version: &dyn Fn() -> usize,
    make_newer: &dyn Fn(),
) {
    let store = Store::at(location).unwrap();
    let old = store.session("s1").unwrap().unwrap();
    assert_eq!((old.label.as_str(), old.account_id), ("old", None));
    assert_eq!(version(), SCHEMA_VERSION);
    store
        .insert_account(&StoredAccount {
            id: "a1".into(),
            name: "Ada".into(),
            role: "trainee".into(),
            token_hash: "ff".into(),
            created_unix_s: 2.0,
        })
        .unwrap();
    drop(store);
    // Opening again changes nothing.
    let store = Store::at(location).unwrap();
    assert_eq!(
        store.account_by_token_hash("ff").unwrap().unwrap().name,
        "Ada"
    );
    drop(store);
    make_newer();
    let e = Store::at(location).unwrap_err().to_string();
    assert!(e.contains("schema version 99"), "{e}");
}
