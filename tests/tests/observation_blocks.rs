//! The observation as blocks: a block of terms, blocks laid end to end, past copies of a block
//! (frames, lag, order, fill), the same term in several places; and the manifests the loader
//! refuses, by field.

mod common;

use policy::{ObsInputs, ObservationBuilder, PolicyLayout};
use robots::{Robot, reference_robot_path};

/// rd-biped's reference follower with its observation replaced by `observation` (TOML).
fn manifest(observation: &str) -> String {
    let path = reference_robot_path().with_file_name("policies/reference_follower.toml");
    let text = std::fs::read_to_string(path).unwrap();
    let head = &text[..text.find("[[observation]]").unwrap()];
    // A top-level key (layout) must come before the first table.
    let (top, tables) = match observation.strip_prefix("layout") {
        Some(_) => observation.split_once("\n\n").unwrap(),
        None => ("", observation),
    };
    format!("{top}\n{head}\n{tables}")
}

fn parse(observation: &str) -> Result<PolicyLayout, policy::PolicyError> {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let path = reference_robot_path().with_file_name("policies/blocks.toml");
    PolicyLayout::parse(&path, &manifest(observation), &robot)
}

/// TWIST2's shape in small: current = [a, b], history = current of the previous 3 ticks oldest
/// first with zeros before the first, future = a again.
const SMALL_TWIST: &str = r#"layout = ["current", "history", "future"]

[[block]]
name = "a"
[[block.terms]]
term = "ramp"

[[block]]
name = "b"
[[block.terms]]
term = "time_step"
scale = 10.0

[[block]]
name = "current"
of = ["a", "b"]

[[block]]
name = "history"
of = ["current"]
frames = 3
lag = 1
order = "oldest_first"
fill = "zeros"

[[block]]
name = "future"
of = ["a"]
"#;

/// The observations of ticks where ψ = 1, 2, 3, … and the time step 0.1, 0.2, ….
fn run(layout: &PolicyLayout, ticks: usize) -> Vec<Vec<f32>> {
    let n = 20;
    let zeros = vec![0.0; n];
    let past = vec![0.0f32; 2 * n];
    let still = common::Still {
        q: zeros.clone(),
        height: 0.5,
    };
    let mut builder = ObservationBuilder::new(layout);
    (1..=ticks)
        .map(|k| {
            let mut obs = vec![f32::NAN; layout.obs_len];
            builder.build(
                &ObsInputs {
                    ramp: k as f64,
                    time_step: k as f64 / 10.0,
                    ..common::at_rest(&zeros, &past, &still)
                },
                &mut obs,
            );
            obs
        })
        .collect()
}

#[test]
fn a_history_block_holds_the_previous_ticks_oldest_first_with_zeros_before_the_first() {
    let layout = parse(SMALL_TWIST).unwrap();
    assert_eq!(layout.obs_len, 2 + 3 * 2 + 1);
    let obs = run(&layout, 5);
    // Tick 1: current (1, 1), nothing before it, the future block again 1.
    assert_eq!(obs[0], [1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
    // Tick 2: the previous tick last in the history (oldest first), the current one left out.
    assert_eq!(obs[1], [2.0, 2.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 2.0]);
    // Tick 5: ticks 2, 3, 4.
    assert_eq!(obs[4], [5.0, 5.0, 2.0, 2.0, 3.0, 3.0, 4.0, 4.0, 5.0]);
    // Each place names its block and how old its values are.
    let described = layout.describe();
    for line in [
        "block current [0..2)",
        "block history [2..8)",
        "block history[t-3] [2..4)",
        "block future [8..9)",
    ] {
        assert!(described.contains(line), "{line:?} in\n{described}");
    }
    assert!(described.contains("3 ticks old (zeros before)"), "{described}");
}

#[test]
fn lag_zero_order_and_fill_change_what_the_copies_hold() {
    let newest = SMALL_TWIST
        .replace("lag = 1", "lag = 0")
        .replace("oldest_first", "newest_first")
        .replace("fill = \"zeros\"", "fill = \"first\"");
    let layout = parse(&newest).unwrap();
    let obs = run(&layout, 4);
    // lag 0: the newest copy is this tick; newest first; before the first tick, its values.
    assert_eq!(obs[0], [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]);
    assert_eq!(obs[1], [2.0, 2.0, 2.0, 2.0, 1.0, 1.0, 1.0, 1.0, 2.0]);
    assert_eq!(obs[3], [4.0, 4.0, 4.0, 4.0, 3.0, 3.0, 2.0, 2.0, 4.0]);
}

#[test]
fn a_plain_observation_list_lays_out_as_before() {
    // One block of terms, named `observation`, each term once and of this tick.
    let layout =
        parse("[[observation]]\nterm = \"ramp\"\n\n[[observation]]\nterm = \"time_step\"\nhistory = 2")
            .unwrap();
    assert_eq!(layout.blocks.len(), 1);
    assert_eq!(layout.blocks[0].name, "observation");
    let obs = run(&layout, 2);
    assert_eq!(obs[0], [1.0, 0.1, 0.1]);
    assert_eq!(obs[1], [2.0, 0.2, 0.1]);
}

#[test]
fn bad_block_layouts_are_refused_by_field() {
    let refused = |text: &str, place: &str, words: &str| {
        let e = parse(text).unwrap_err();
        assert!(
            e.place == place && e.message.contains(words),
            "wanted {place}: …{words}…, got {e}"
        );
    };
    refused(
        &SMALL_TWIST.replace("lag = 1", "lag = 63"),
        "block[3] (history).lag",
        "beyond the 64 a history holds",
    );
    refused(
        &SMALL_TWIST.replace(
            r#"layout = ["current", "history", "future"]"#,
            r#"layout = ["current", "histroy"]"#,
        ),
        "layout[1]",
        "no block \"histroy\"",
    );
    refused(
        &SMALL_TWIST.replace(r#"of = ["a", "b"]"#, r#"of = ["a", "future"]"#),
        "block[2] (current).of[1]",
        "no block \"future\" above this one",
    );
    refused(
        &SMALL_TWIST.replace("frames = 3\n", ""),
        "block[3] (history).frames",
        "give `frames`",
    );
    refused(
        &SMALL_TWIST.replace(
            "term = \"time_step\"\nscale = 10.0",
            "term = \"ramp\"\n[[block.terms]]\nterm = \"ramp\"",
        ),
        "block[1] (b).terms[1] (ramp)",
        "the same term as block[1] (b).terms[0] (ramp)",
    );
    refused(
        &SMALL_TWIST.replace(
            "term = \"time_step\"",
            "term = \"ref_body_pos\"\nbodies = [\"no_such_body\"]",
        ),
        "block[1] (b).terms[0] (ref_body_pos)",
        "\"no_such_body\" is not a body of",
    );
    refused(
        &SMALL_TWIST.replace(
            "term = \"time_step\"",
            "term = \"ref_root_lin_vel\"\naxes = \"xx\"",
        ),
        "block[1] (b).terms[0] (ref_root_lin_vel)",
        "axes = \"xx\"",
    );
    refused(
        &format!("{SMALL_TWIST}\n[[observation]]\nterm = \"ramp\"\n"),
        "observation",
        "not both",
    );
}

#[test]
fn the_same_term_in_two_blocks_is_one_definition_computed_once() {
    let layout = parse(SMALL_TWIST).unwrap();
    // `a`'s ramp shows in current, three history copies and future: five places, one definition.
    let ramp: Vec<_> = layout.slots.iter().filter(|s| s.term.name() == "ramp").collect();
    assert_eq!(ramp.len(), 5);
    assert!(ramp.iter().all(|s| s.source == ramp[0].source));
    assert_eq!(layout.terms.len(), 2);
    assert_eq!(
        ramp.iter().map(|s| s.delay).collect::<Vec<_>>(),
        [0, 3, 2, 1, 0],
        "current, history oldest first, future"
    );
}
