//! Every fuzz target's committed corpus (its seeds and every input a fuzzer found) replayed
//! through the target on stable, in the suite's own build: a regression in a parser fails here
//! without the nightly fuzzing build. Fuzzing for new inputs is `scripts/fuzz` (nightly).

use std::path::PathBuf;

fn corpus() -> PathBuf {
    test_support::fixtures::workspace_root().join("tests/fuzz/corpus")
}

#[test]
fn every_target_has_a_corpus_and_every_corpus_a_target() {
    let mut folders: Vec<String> = std::fs::read_dir(corpus())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    folders.sort();
    let mut targets: Vec<String> = fuzz_targets::TARGETS
        .iter()
        .map(|(n, _)| (*n).to_owned())
        .collect();
    targets.sort();
    assert_eq!(folders, targets);
}

#[test]
fn every_corpus_input_replays_through_its_target_without_a_panic() {
    let mut failed = Vec::new();
    let mut replayed = 0;
    for (name, run) in fuzz_targets::TARGETS {
        let mut inputs: Vec<PathBuf> = std::fs::read_dir(corpus().join(name))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        inputs.sort();
        for input in inputs {
            let data = std::fs::read(&input).unwrap();
            if std::panic::catch_unwind(|| run(&data)).is_err() {
                failed.push(input.display().to_string());
            }
            replayed += 1;
        }
    }
    assert!(
        failed.is_empty(),
        "{} of {replayed} inputs panicked: {failed:#?}",
        failed.len()
    );
    assert!(replayed >= 50, "{replayed} inputs");
}
