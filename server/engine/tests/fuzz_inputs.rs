//! The fuzz targets' inputs under `cargo test`, without libFuzzer's instrumented build: every
//! regression (`fuzz/regressions/`, `fuzz/artifacts/`) and every seed (`fuzz/corpus/`) run
//! through the fuzz targets' own bodies (`fuzz/src/targets.rs`, `fuzz/src/scene_input.rs`),
//! then seeded mutations of each seed (bytes flipped, cut, repeated, deleted, boundary
//! integers written, spliced with another seed). An input fails on a panic, or on reserving
//! more than the process's 2 GiB of address space (the run aborts, naming the allocation's
//! size). Coverage-guided
//! fuzzing is `scripts/fuzz.sh` (`smoke`, `release`), run before a release.

use std::panic::{AssertUnwindSafe, catch_unwind};

use cathlab_engine::stress::Dice;
use std::path::{Path, PathBuf};

// The fuzz crate's support (without its allocator: the workspace forbids unsafe code), reader
// targets and scene target, included by their paths; they reach the support as `super::`.
#[path = "../../../fuzz/src/support.rs"]
mod support;
use support::{report, split_files, write_scratch};

/// What the fuzz crate's `start` does, less its allocator's limit: the readers' limits and
/// the panic hook. The 1 GiB limit on allocations is this process's address space instead.
fn start() {
    support::start_common();
}

/// Most address space the test may take (bytes): an input that makes a reader reserve more
/// than the 1 GiB the fuzz targets allow (beyond this process's own ~0.5 GiB) fails to
/// allocate and aborts the run, naming the size.
const ADDRESS_SPACE_BYTES: u64 = 2 << 30;

#[path = "../../../fuzz/src/targets.rs"]
mod targets;

#[path = "../../../fuzz/src/scene_input.rs"]
mod scene_input;

/// Mutations of each seed.
const MUTATIONS_PER_SEED: usize = 200;

fn fuzz_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz")
}

fn files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .flatten()
                .map(|e| e.path())
                .filter(|p| p.is_file())
                .collect()
        })
        .unwrap_or_default();
    files.sort();
    files
}

/// Integers at the edges of what headers and counts hold.
const BOUNDARIES: [u64; 8] = [
    0,
    1,
    0x7F,
    0xFFFF,
    0x7FFF_FFFF,
    0xFFFF_FFFF,
    0x7FFF_FFFF_FFFF_FFFF,
    u64::MAX,
];

/// One mutation of `seed` (`other`: another seed of the same target, to splice with).
fn mutate(seed: &[u8], other: &[u8], dice: &mut Dice) -> (Vec<u8>, &'static str) {
    let mut data = seed.to_vec();
    if data.is_empty() {
        return (other.to_vec(), "other");
    }
    let at = dice.below(data.len());
    let kind = match dice.below(7) {
        0 => {
            for _ in 0..1 + dice.below(4) {
                let i = dice.below(data.len());
                data[i] ^= 1 << dice.below(8);
            }
            "bits flipped"
        }
        1 => {
            data.truncate(at);
            "cut"
        }
        2 => {
            let len = 1 + dice.below((data.len() - at).min(256));
            let chunk = data[at..at + len].to_vec();
            for _ in 0..1 + dice.below(16) {
                data.splice(at..at, chunk.iter().copied());
            }
            "repeated"
        }
        3 => {
            let len = 1 + dice.below((data.len() - at).min(256));
            data.drain(at..at + len);
            "deleted"
        }
        4 => {
            let value = BOUNDARIES[dice.below(BOUNDARIES.len())];
            let width = [1, 2, 4, 8][dice.below(4)];
            let bytes = value.to_le_bytes();
            for (k, b) in bytes[..width].iter().enumerate() {
                if let Some(slot) = data.get_mut(at + k) {
                    *slot = *b;
                }
            }
            "boundary integer"
        }
        5 => {
            // Text formats: a run of digits made huge, or negative.
            let digits = ["99999999999999999999", "-1", "1e308", "nan", "4294967296"];
            data.splice(at..at, digits[dice.below(digits.len())].bytes());
            "number written"
        }
        _ => {
            let from = dice.below(other.len().max(1));
            let len = dice.below(other.len().saturating_sub(from).min(512) + 1);
            data.splice(
                at..,
                other[from.min(other.len())..from.min(other.len()) + len]
                    .iter()
                    .copied(),
            );
            "spliced"
        }
    };
    (data, kind)
}

#[test]
fn every_regression_seed_and_seeded_mutation_is_read_without_a_panic() {
    #[cfg(unix)]
    {
        use rustix::process::{Resource, Rlimit, getrlimit, setrlimit};
        let hard = getrlimit(Resource::As).maximum;
        let current = hard.map_or(ADDRESS_SPACE_BYTES, |h| h.min(ADDRESS_SPACE_BYTES));
        setrlimit(
            Resource::As,
            Rlimit {
                current: Some(current),
                maximum: hard,
            },
        )
        .unwrap();
    }
    let root = fuzz_dir();
    let mut targets: Vec<targets::Target> = targets::readers().to_vec();
    targets.push(("scene", scene_input::scene));
    let mut failures = Vec::new();
    let mut runs = 0usize;
    let mut run = |target: &str, body: fn(&[u8]), data: &[u8], what: &str| {
        runs += 1;
        if catch_unwind(AssertUnwindSafe(|| body(data))).is_err() {
            failures.push(format!("{target}: {what}"));
        }
    };
    for (target, body) in &targets {
        for dir in ["regressions", "artifacts"] {
            for file in files(&root.join(dir).join(target)) {
                let data = std::fs::read(&file).unwrap();
                run(target, *body, &data, &file.display().to_string());
            }
        }
        let seeds: Vec<(PathBuf, Vec<u8>)> = files(&root.join("corpus").join(target))
            .into_iter()
            .map(|f| {
                let data = std::fs::read(&f).unwrap();
                (f, data)
            })
            .collect();
        assert!(!seeds.is_empty(), "fuzz/corpus/{target} has seeds");
        for (i, (file, data)) in seeds.iter().enumerate() {
            run(target, *body, data, &file.display().to_string());
            let other = &seeds[(i + 1) % seeds.len()].1;
            let mut dice = Dice(0xC47_u64 ^ ((i as u64) << 32) ^ target.len() as u64);
            for m in 0..MUTATIONS_PER_SEED {
                let (mutant, kind) = mutate(data, other, &mut dice);
                run(
                    target,
                    *body,
                    &mutant,
                    &format!("{} mutation {m} ({kind})", file.display()),
                );
            }
        }
    }
    println!("{runs} inputs read by {} targets", targets.len());
    assert!(failures.is_empty(), "panicked on: {failures:#?}");
}
