//! The live view: a lockstep run served over Foxglove's WebSocket protocol (`foxglove.sdk.v1`)
//! to a client in the test, which subscribes and receives joint states and transforms, and a
//! viewer that never comes does not hold the robot forever.

use std::collections::HashMap;

use prost::Message as _;
use std::time::Duration;

use test_support::bin::Running;
use test_support::fixtures::workspace_root;
use tungstenite::Message;
use tungstenite::client::IntoClientRequest;

fn scratch(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("live-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The fields of `foxglove.FrameTransforms` this test reads, by the schema's field numbers (the
/// foxglove crate's types only encode).
#[derive(Clone, PartialEq, prost::Message)]
struct Transforms {
    #[prost(message, repeated, tag = "1")]
    transforms: Vec<Transform>,
}

#[derive(Clone, PartialEq, prost::Message)]
struct Transform {
    #[prost(string, tag = "3")]
    child_frame_id: String,
}

/// The fields of `foxglove.SceneUpdate` this test reads.
#[derive(Clone, PartialEq, prost::Message)]
struct Scene {
    #[prost(message, repeated, tag = "2")]
    entities: Vec<Entity>,
}

#[derive(Clone, PartialEq, prost::Message)]
struct Entity {
    #[prost(string, tag = "2")]
    frame_id: String,
    #[prost(message, repeated, tag = "8")]
    cubes: Vec<Primitive>,
}

/// Any primitive, its fields unread.
#[derive(Clone, PartialEq, prost::Message)]
struct Primitive {}

/// A viewer of `play`'s live view: connected over the protocol's current name to the address the
/// run prints.
fn viewer(
    play: &mut Running,
) -> tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<std::net::TcpStream>> {
    let line = play.wait_for("live: ws://", Duration::from_secs(120));
    let url = line.split_whitespace().nth(1).unwrap().to_owned();
    assert!(url.starts_with("ws://127.0.0.1:"), "{line}");
    let mut request = url.as_str().into_client_request().unwrap();
    request
        .headers_mut()
        .insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().unwrap());
    tungstenite::connect(request).unwrap().0
}

/// A text message's JSON (the protocol's operations); none for binary data.
fn json_of(m: Message) -> Option<serde_json::Value> {
    let Message::Text(text) = m else {
        return None;
    };
    Some(serde_json::from_str(&text).unwrap())
}

#[test]
fn a_lockstep_run_streams_joint_states_and_transforms_to_a_subscribed_client() {
    let dir = scratch("stream");
    let record = dir.join("run.mcap");
    let clip = workspace_root().join("robots/biped/clips/squat.csv");
    let mut play = Running::start(&[
        "play",
        "--clip",
        clip.to_str().unwrap(),
        "--record",
        record.to_str().unwrap(),
        "--live",
        "127.0.0.1:0",
        "--live-wait",
        "120",
    ]);
    let mut ws = viewer(&mut play);
    // serverInfo, then the channels advertised: the recording's topics.
    let mut channels: HashMap<String, u64> = HashMap::new();
    let mut schemas: HashMap<String, (String, String)> = HashMap::new();
    let mut capabilities = Vec::new();
    while !(channels.contains_key("/joint_state")
        && channels.contains_key("/tf")
        && channels.contains_key("/robot"))
    {
        let Some(v) = json_of(ws.read().unwrap()) else {
            continue;
        };
        if v["op"] == "serverInfo" {
            capabilities = v["capabilities"].as_array().cloned().unwrap_or_default();
        }
        if v["op"] == "advertise" {
            for c in v["channels"].as_array().unwrap() {
                let topic = c["topic"].as_str().unwrap().to_owned();
                channels.insert(topic.clone(), c["id"].as_u64().unwrap());
                let schema = (
                    c["schemaName"].as_str().unwrap().to_owned(),
                    c["encoding"].as_str().unwrap().to_owned(),
                );
                schemas.insert(topic, schema);
            }
        }
    }
    // What the run is, as Foxglove's Parameters panel asks for it (read-only).
    assert!(capabilities.iter().any(|c| c == "parameters"), "{capabilities:?}");
    let ask = serde_json::json!({"op": "getParameters", "parameterNames": [], "id": "about"});
    ws.send(Message::Text(ask.to_string().into())).unwrap();
    let about: HashMap<String, String> = loop {
        let Some(v) = json_of(ws.read().unwrap()) else {
            continue;
        };
        if v["op"] == "parameterValues" {
            assert_eq!(v["id"], "about", "{v}");
            break v["parameters"]
                .as_array()
                .unwrap()
                .iter()
                .map(|p| {
                    (
                        p["name"].as_str().unwrap().to_owned(),
                        p["value"].as_str().unwrap_or("").to_owned(),
                    )
                })
                .collect();
        }
    };
    assert_eq!(
        about["robodeploy/version"],
        env!("CARGO_PKG_VERSION"),
        "{about:?}"
    );
    assert!(!about["robodeploy/commit"].is_empty(), "{about:?}");
    assert_eq!(about["run/robot_name"], "rd-biped", "{about:?}");
    assert!(
        about["run/policy"].ends_with("reference_follower.toml"),
        "{about:?}"
    );
    assert!(about["run/clip"].ends_with("squat.csv"), "{about:?}");
    let subscribe = serde_json::json!({
        "op": "subscribe",
        "subscriptions": [
            {"id": 1, "channelId": channels["/joint_state"]},
            {"id": 2, "channelId": channels["/tf"]},
            {"id": 3, "channelId": channels["/robot"]},
        ],
    });
    ws.send(Message::Text(subscribe.to_string().into())).unwrap();
    // The recording's typed channels: the project's joint states, Foxglove's transforms and scene.
    assert_eq!(
        schemas["/joint_state"],
        ("robodeploy.JointStates".into(), "protobuf".into())
    );
    assert_eq!(
        schemas["/tf"],
        ("foxglove.FrameTransforms".into(), "protobuf".into())
    );
    assert_eq!(
        schemas["/robot"],
        ("foxglove.SceneUpdate".into(), "protobuf".into())
    );
    // Message data: opcode 1, subscription (u32), log time (u64, ns), the protobuf message.
    let (mut states, mut transforms, mut scenes) = (Vec::new(), Vec::new(), Vec::new());
    let mut last_time = 0u64;
    while states.len() < 50 || transforms.len() < 50 || scenes.is_empty() {
        let Message::Binary(b) = ws.read().unwrap() else {
            continue;
        };
        assert_eq!(b[0], 1, "message data");
        let sub = u32::from_le_bytes(b[1..5].try_into().unwrap());
        let time = u64::from_le_bytes(b[5..13].try_into().unwrap());
        let data = &b[13..];
        match sub {
            1 => {
                assert!(time >= last_time, "in time order");
                last_time = time;
                states.push(telemetry_schema::JointStates::decode(data).unwrap());
            }
            2 => transforms.push(Transforms::decode(data).unwrap()),
            3 => scenes.push(Scene::decode(data).unwrap()),
            other => panic!("subscription {other}"),
        }
    }
    drop(ws);
    let joints = &states[40].joints;
    assert_eq!(joints.len(), 20, "every rd-biped joint: {:?}", states[40]);
    assert!(
        joints
            .iter()
            .all(|j| j.position.is_finite() && !j.name.is_empty())
    );
    let frames: std::collections::BTreeSet<_> = transforms[40]
        .transforms
        .iter()
        .map(|t| t.child_frame_id.clone())
        .collect();
    assert!(frames.len() > 5, "the links' frames: {frames:?}");
    // The robot's geometry reaches a viewer that joined after the run began.
    assert!(
        scenes[0]
            .entities
            .iter()
            .any(|e| e.frame_id == "left_foot" && !e.cubes.is_empty()),
        "{:?}",
        scenes[0].entities.iter().map(|e| &e.frame_id).collect::<Vec<_>>()
    );
    let done = play
        .finish_within(Duration::from_secs(300))
        .expect("the run ends");
    assert!(done.status.success(), "{}{}", done.stdout, done.stderr);
    assert!(
        done.stdout.contains("live: a viewer subscribed; starting"),
        "{}",
        done.stdout
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_viewer_that_never_comes_holds_the_start_only_as_long_as_asked() {
    let dir = scratch("nobody");
    let record = dir.join("run.mcap");
    let play = Running::start(&[
        "play",
        "--max-seconds",
        "1",
        "--record",
        record.to_str().unwrap(),
        "--live",
        "127.0.0.1:0",
        "--live-wait",
        "1",
    ]);
    let done = play
        .finish_within(Duration::from_secs(300))
        .expect("the run ends");
    assert!(done.status.success(), "{}{}", done.stdout, done.stderr);
    assert!(
        done.stdout.contains("live: no viewer; starting anyway"),
        "{}",
        done.stdout
    );
    // A non-loopback address is only used when given; a bad one is refused by name.
    let (ok, _, stderr) = test_support::bin::run(&["play", "--live", "nowhere:1", "--max-seconds", "1"]);
    assert!(!ok && stderr.contains("--live"), "{stderr}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Foxglove's Teleop panel, as the protocol carries it: a viewer advertises `/cmd_vel`
/// (geometry_msgs/Twist in JSON) and publishes on it; with `--viewer-commands` the walking policy
/// takes it as its forward command.
#[test]
fn a_viewer_publishing_cmd_vel_drives_a_command_driven_policy() {
    let dir = scratch("teleop-panel");
    let root = workspace_root();
    let mut play = Running::start(&[
        "play",
        "--robot",
        root.join("robots/mini/robot.toml").to_str().unwrap(),
        "--policy",
        root.join("robots/mini/policies/walk.toml").to_str().unwrap(),
        "--max-seconds",
        "40",
        "--record",
        dir.join("run.mcap").to_str().unwrap(),
        "--live",
        "127.0.0.1:0",
        "--live-wait",
        "120",
        "--viewer-commands",
    ]);
    let mut ws = viewer(&mut play);
    let mut joint_state = None;
    let mut capabilities = Vec::new();
    while joint_state.is_none() {
        let Some(v) = json_of(ws.read().unwrap()) else {
            continue;
        };
        if v["op"] == "serverInfo" {
            capabilities = v["capabilities"].as_array().cloned().unwrap_or_default();
        }
        if v["op"] == "advertise" {
            joint_state = v["channels"]
                .as_array()
                .unwrap()
                .iter()
                .find(|c| c["topic"] == "/joint_state")
                .map(|c| c["id"].as_u64().unwrap());
        }
    }
    assert!(
        capabilities.iter().any(|c| c == "clientPublish"),
        "{capabilities:?}"
    );
    let advertise = serde_json::json!({"op": "advertise", "channels": [
        {"id": 7, "topic": "/cmd_vel", "encoding": "json", "schemaName": "geometry_msgs/Twist"}
    ]});
    ws.send(Message::Text(advertise.to_string().into())).unwrap();
    // Forward at 0.2 m/s, as the panel's up arrow sends it; then the run starts (a subscription).
    let twist = serde_json::json!({"linear": {"x": 0.2, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}});
    let mut frame = vec![1u8];
    frame.extend_from_slice(&7u32.to_le_bytes());
    frame.extend_from_slice(twist.to_string().as_bytes());
    ws.send(Message::Binary(frame.clone().into())).unwrap();
    let subscribe =
        serde_json::json!({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": joint_state}]});
    ws.send(Message::Text(subscribe.to_string().into())).unwrap();
    // Keep publishing while the run streams (the socket's reads pace the sends).
    let mut sent = 1;
    while let Ok(m) = ws.read() {
        if matches!(m, Message::Close(_)) {
            break;
        }
        if sent < 2000 {
            ws.send(Message::Binary(frame.clone().into())).unwrap();
            sent += 1;
        }
    }
    let out = play.finish();
    assert!(out.status.success(), "{}\n{}", out.stdout, out.stderr);
    let accepted: u64 = out
        .stdout
        .lines()
        .filter(|l| l.contains(" accepted"))
        .find_map(|l| l.strip_prefix("commands: "))
        .and_then(|l| l.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| panic!("no command count:\n{}", out.stdout));
    assert!(
        accepted >= 10,
        "{accepted} of {sent} twists taken:\n{}",
        out.stdout
    );
    let forward = out
        .stdout
        .lines()
        .find(|l| l.starts_with("forward"))
        .unwrap_or_else(|| panic!("{}", out.stdout));
    let commanded: f64 = forward
        .split("commanded ")
        .nth(1)
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| panic!("{forward}"));
    assert!(commanded > 0.05, "{forward}");
    std::fs::remove_dir_all(&dir).unwrap();
}
