//! Emulated motors served over socketcand on 127.0.0.1, in wall-clock time: driven by the
//! project's own client and driver, by python-can (an independent client), and fed garbage.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::Duration;

use firmware_bridge::can::socketcand::{ClientLimits, SocketcandClient, SocketcandServer};
use firmware_bridge::can::virtual_bus::VirtualCanBus;
use firmware_bridge::can::{CanBus, CanFrame, CanId};
use firmware_bridge::mit::driver::{JointCommand, MitBusDriver, MitJointConfig};
use firmware_bridge::mit::firmware::MitFirmwareConfig;
use firmware_bridge::mit::models::find;
use firmware_bridge::mit::rig::MitRig;
use firmware_bridge::plant::InertiaPlant;
use firmware_bridge::time::SimInstant;
use firmware_bridge::time::WallClockRunner;

struct Served {
    server: SocketcandServer,
    _runner: WallClockRunner,
}

/// An AK80-9 (ID 1) and a DM-J4310 (ID 2) on one bus, served on a free loopback port.
fn serve() -> Served {
    let bus = VirtualCanBus::new("can0", 1_000_000);
    let mut rig = MitRig::new(vec![bus.clone()], Duration::from_micros(500));
    rig.add_motor(
        0,
        MitFirmwareConfig::new(1, find("AK80-9").unwrap()),
        InertiaPlant::new(0.01, 0.05, 0.0, 0.0),
    );
    rig.add_motor(
        0,
        MitFirmwareConfig::new(2, find("DM-J4310").unwrap()),
        InertiaPlant::new(0.005, 0.02, 0.0, 0.0),
    );
    let rig = rig.shared();
    let runner = WallClockRunner::spawn(rig, Duration::from_micros(200)).unwrap();
    let clock_start = std::time::Instant::now();
    let server = SocketcandServer::spawn("127.0.0.1:0".parse().unwrap(), "can0", bus.attach(), move || {
        clock_start.elapsed()
    })
    .unwrap();
    Served {
        server,
        _runner: runner,
    }
}

#[test]
fn python_can_enables_commands_and_reads_an_emulated_motor() {
    let served = serve();
    let m = find("AK80-9").unwrap();
    let script =
        test_support::fixtures::workspace_root().join("firmware-bridge/tests/python/mit_over_socketcand.py");
    let out = std::process::Command::new(test_support::fixtures::venv_python())
        .arg(script)
        .args(["127.0.0.1", &served.server.local_addr().port().to_string(), "1"])
        .args([m.p_max, m.v_max, m.t_max].map(|x| x.to_string()))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "python-can run failed\nstdout: {stdout}\nstderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(summary["enable"]["err"], 0);
    let (p, target) = (
        summary["final"]["p"].as_f64().unwrap(),
        summary["target"].as_f64().unwrap(),
    );
    assert!((p - target).abs() < 0.05, "{summary}");
    assert_eq!(served.server.malformed(), 0);
}

#[test]
fn the_driver_runs_over_tcp_like_over_any_bus() {
    let served = serve();
    let client =
        SocketcandClient::connect(served.server.local_addr(), "can0", Duration::from_secs(2)).unwrap();
    let joint = |name: &str, id: u8, model: &str| {
        let model = find(model).unwrap();
        MitJointConfig::new(name, id, model)
    };
    let joints = vec![joint("hip", 1, "AK80-9"), joint("wrist", 2, "DM-J4310")];
    let mut driver = MitBusDriver::new(client, joints, Duration::from_millis(20)).unwrap();
    driver.enable_all().unwrap();
    let cmds = [0.5, -0.4].map(|q| JointCommand {
        q,
        qd: 0.0,
        kp: 20.0,
        kd: 0.8,
        tau: 0.0,
    });
    for _ in 0..100 {
        driver.cycle(&cmds).unwrap();
        std::thread::sleep(Duration::from_millis(10));
    }
    for (fb, c) in driver.feedback().iter().zip(&cmds) {
        assert!((fb.q - c.q).abs() < 0.03, "{} vs {}", fb.q, c.q);
    }
    assert!(driver.stats().missed_replies < 5, "{:?}", driver.stats());
    driver.disable_all().unwrap();
}

#[test]
fn garbage_on_the_wire_is_counted_and_the_session_survives() {
    let served = serve();
    let mut s = TcpStream::connect(served.server.local_addr()).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
    let mut buf = [0u8; 64];
    let n = s.read(&mut buf).unwrap();
    assert_eq!(&buf[..n], b"< hi >");
    s.write_all(b"< open can0 >").unwrap();
    let n = s.read(&mut buf).unwrap();
    assert_eq!(&buf[..n], b"< ok >");
    s.write_all(b"< rawmode >").unwrap();
    let n = s.read(&mut buf).unwrap();
    assert_eq!(&buf[..n], b"< ok >");
    s.write_all(
        b"hello there< send 800 1 00 >< send 001 9 00 >< bogus >< send 001 8 FF FF FF FF FF FF FF FC >",
    )
    .unwrap();
    // The valid enable frame after the garbage still reaches the motor, which answers.
    let mut text = String::new();
    let deadline = std::time::Instant::now() + Duration::from_secs(2);
    while !text.contains("< frame 000 ") && std::time::Instant::now() < deadline {
        let n = s.read(&mut buf).unwrap_or(0);
        text.push_str(&String::from_utf8_lossy(&buf[..n]));
    }
    assert!(text.contains("< frame 000 "), "{text}");
    assert_eq!(served.server.malformed(), 4);
}

/// A bus with no motors, served with short client limits; the test puts frames on it itself.
fn serve_bare(limits: ClientLimits) -> (VirtualCanBus, SocketcandServer) {
    let bus = VirtualCanBus::new("can0", 1_000_000);
    let server = SocketcandServer::spawn_with(
        "127.0.0.1:0".parse().unwrap(),
        "can0",
        bus.attach(),
        || Duration::ZERO,
        limits,
    )
    .unwrap();
    (bus, server)
}

/// Reads until `want` arrives or the peer closes (or 20 s pass); returns everything read.
fn read_until(s: &mut TcpStream, want: &str) -> String {
    s.set_read_timeout(Some(Duration::from_millis(200))).unwrap();
    let give_up = std::time::Instant::now() + Duration::from_secs(20);
    let mut text = String::new();
    let mut buf = [0u8; 256];
    while !text.contains(want) && std::time::Instant::now() < give_up {
        match s.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => text.push_str(&String::from_utf8_lossy(&buf[..n])),
            Err(_) => {}
        }
    }
    text
}

fn raw_mode(addr: std::net::SocketAddr) -> TcpStream {
    let mut s = TcpStream::connect(addr).unwrap();
    assert!(read_until(&mut s, "< hi >").contains("< hi >"));
    s.write_all(b"< open can0 >< rawmode >").unwrap();
    let text = read_until(&mut s, "< ok >< ok >");
    assert!(text.contains("< ok >< ok >"), "{text}");
    s
}

const LONG: Duration = Duration::from_secs(600);

#[test]
fn a_second_client_is_refused_at_once_and_served_when_the_first_leaves() {
    let (_bus, server) = serve_bare(ClientLimits {
        handshake: LONG,
        idle: LONG,
        stalled_reader: LONG,
    });
    let first = raw_mode(server.local_addr());
    let mut second = TcpStream::connect(server.local_addr()).unwrap();
    let text = read_until(&mut second, "< error bus in use by another client >");
    assert!(text.contains("< error bus in use by another client >"), "{text}");
    drop(first);
    // Once the first client is gone the bus is free again (retry: the server notices the close).
    let give_up = std::time::Instant::now() + Duration::from_secs(20);
    loop {
        let mut next = TcpStream::connect(server.local_addr()).unwrap();
        if read_until(&mut next, "< hi >").contains("< hi >") {
            break;
        }
        assert!(std::time::Instant::now() < give_up, "the bus stayed taken");
    }
}

#[test]
fn a_client_that_never_finishes_the_handshake_or_goes_quiet_is_dropped() {
    let (_bus, server) = serve_bare(ClientLimits {
        handshake: Duration::from_millis(300),
        idle: Duration::from_millis(300),
        stalled_reader: LONG,
    });
    let mut mute = TcpStream::connect(server.local_addr()).unwrap();
    let text = read_until(&mut mute, "< error handshake timeout >");
    assert!(
        text.starts_with("< hi >") && text.contains("< error handshake timeout >"),
        "{text}"
    );
    let mut quiet = raw_mode(server.local_addr());
    let text = read_until(&mut quiet, "< error idle timeout >");
    assert!(text.contains("< error idle timeout >"), "{text}");
    // A client that keeps talking (`< echo >` as a keep-alive) stays: over 1 s, more than three
    // idle limits, the server only ever answers its echoes.
    let mut talking = raw_mode(server.local_addr());
    let until = std::time::Instant::now() + Duration::from_secs(1);
    while std::time::Instant::now() < until {
        talking.write_all(b"< echo >").unwrap();
        let text = read_until(&mut talking, "< echo >");
        assert!(text.contains("< echo >") && !text.contains("error"), "{text}");
        // Then 100 ms of listening (a third of the idle limit): the server must say nothing.
        talking
            .set_read_timeout(Some(Duration::from_millis(100)))
            .unwrap();
        let mut buf = [0u8; 256];
        match talking.read(&mut buf) {
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            other => panic!("the server spoke to a talking client: {other:?} {:?}", &buf[..8]),
        }
    }
}

#[test]
fn a_client_that_stops_reading_is_dropped_and_frees_the_bus() {
    let (bus, server) = serve_bare(ClientLimits {
        handshake: LONG,
        idle: LONG,
        stalled_reader: Duration::from_millis(300),
    });
    let _stalled = raw_mode(server.local_addr());
    let sender = bus.attach();
    let frame = CanFrame::new(CanId::standard(0x123).unwrap(), &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
    let mut t = 0u64;
    let give_up = std::time::Instant::now() + Duration::from_secs(60);
    // Frames flow to a client that reads none of them until its socket buffers are full; then the
    // server gives up on it and takes the next client.
    loop {
        for _ in 0..200 {
            let _ = sender.send(&frame);
            t += 200_000;
            bus.set_now(SimInstant::from_nanos(t));
        }
        let mut next = TcpStream::connect(server.local_addr()).unwrap();
        let text = read_until(&mut next, ">");
        if text.contains("< hi >") {
            break;
        }
        assert!(text.contains("in use"), "{text}");
        assert!(
            std::time::Instant::now() < give_up,
            "the stalled client kept the bus"
        );
    }
}

#[test]
#[allow(
    unsafe_code,
    reason = "a signal handler installed without SA_RESTART, and signals sent to the reading thread, to interrupt its read"
)]
fn a_read_interrupted_by_a_signal_waits_on_and_the_bus_is_not_lost() {
    // SIGSTOP/SIGCONT, a profiler or a debugger interrupt a blocked read with EINTR; it was
    // taken for a lost bus (exit 5).
    extern "C" fn ignore(_: libc::c_int) {}
    // SAFETY: a zeroed sigaction with a handler that does nothing, installed for SIGUSR1 only.
    unsafe {
        let mut action: libc::sigaction = std::mem::zeroed();
        action.sa_sigaction = ignore as extern "C" fn(libc::c_int) as usize;
        action.sa_flags = 0;
        libc::sigemptyset(&mut action.sa_mask);
        assert_eq!(libc::sigaction(libc::SIGUSR1, &action, std::ptr::null_mut()), 0);
    }
    // A bus with nothing on it: the read waits its whole deadline.
    let bus = VirtualCanBus::new("can0", 1_000_000);
    let start = std::time::Instant::now();
    let server = SocketcandServer::spawn("127.0.0.1:0".parse().unwrap(), "can0", bus.attach(), move || {
        start.elapsed()
    })
    .unwrap();
    let mut client = SocketcandClient::connect(server.local_addr(), "can0", Duration::from_secs(5)).unwrap();
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    let reader = std::thread::Builder::new()
        .name("interrupted-reader".into())
        .spawn(move || {
            // SAFETY: pthread_self has no preconditions.
            tx.send(unsafe { libc::pthread_self() }).unwrap();
            client.recv_until(std::time::Instant::now() + Duration::from_millis(500))
        })
        .unwrap();
    let thread = rx.recv().unwrap();
    let mut sent = 0;
    while !reader.is_finished() {
        // SAFETY: the thread is not joined yet, so its id is valid (a finished one gets ESRCH).
        if unsafe { libc::pthread_kill(thread, libc::SIGUSR1) } == 0 {
            sent += 1;
        }
        // Signals as fast as they go: the reader must ride out every one.
        std::thread::yield_now();
    }
    let result = reader.join().unwrap();
    assert!(sent > 10, "{sent} signals");
    assert!(matches!(result, Ok(None)), "{result:?}");
}
