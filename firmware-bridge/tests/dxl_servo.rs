//! The emulated X-series servo at the byte level: what it answers, per the e-Manual, to good,
//! bad and hostile instruction packets.

use std::time::Duration;

use firmware_bridge::dxl::models::find;
use firmware_bridge::dxl::packet::{self, BROADCAST_ID, Decoded, inst};
use firmware_bridge::dxl::servo::{ServoConfig, XSeriesServo};
use firmware_bridge::dxl::table::{addr, status};
use firmware_bridge::dxl::wire::{ServoChain, WireTiming};
use firmware_bridge::half_duplex::LineDevices;
use firmware_bridge::time::{SimInstant, SimRng};

const BAUD: u32 = 1_000_000;

fn chain(ids: &[u8]) -> ServoChain {
    let servos = ids
        .iter()
        .map(|&id| {
            let model = find(if id == 3 { "XL430-W250" } else { "XM430-W350" }).unwrap();
            XSeriesServo::new(
                model,
                ServoConfig::new(id).on_line(BAUD, Duration::from_micros(100)),
            )
        })
        .collect();
    ServoChain::new(servos, WireTiming::new(BAUD))
}

/// Status packets (id, error, params) the chain sends for `bytes`, with their start times.
fn exchange(c: &mut ServoChain, at: SimInstant, bytes: &[u8]) -> Vec<(u8, u8, Vec<u8>, SimInstant)> {
    c.receive(bytes, at);
    let mut wire = Vec::new();
    c.take_replies_due(at + Duration::from_secs(1), &mut |start, b| {
        wire.push((start, b.to_vec()));
    });
    let mut scratch = [0u8; 1024];
    wire.into_iter()
        .map(|(start, b)| match packet::decode(&b, &mut scratch) {
            Decoded::Packet(p, used) => {
                assert_eq!(used, b.len());
                assert_eq!(p.instruction, packet::STATUS);
                (p.id, p.error.unwrap(), p.params.to_vec(), start)
            }
            other => panic!("the servo sent a bad packet: {other:?}"),
        })
        .collect()
}

fn instruction(id: u8, instruction: u8, params: &[u8]) -> Vec<u8> {
    let mut buf = vec![0u8; 16 + 2 * params.len()];
    let n = packet::encode_instruction(id, instruction, params, &mut buf).unwrap();
    buf.truncate(n);
    buf
}

fn write(id: u8, address: u16, data: &[u8]) -> Vec<u8> {
    let mut p = address.to_le_bytes().to_vec();
    p.extend_from_slice(data);
    instruction(id, inst::WRITE, &p)
}

fn read(id: u8, address: u16, len: u16) -> Vec<u8> {
    let mut p = address.to_le_bytes().to_vec();
    p.extend_from_slice(&len.to_le_bytes());
    instruction(id, inst::READ, &p)
}

fn error_of(c: &mut ServoChain, bytes: &[u8]) -> u8 {
    let replies = exchange(c, SimInstant::ZERO, bytes);
    assert_eq!(replies.len(), 1, "one status packet expected");
    replies[0].1
}

#[test]
fn ping_read_and_write_answer_as_the_manual_says() {
    let mut c = chain(&[1]);
    let r = exchange(&mut c, SimInstant::ZERO, &instruction(1, inst::PING, &[]));
    assert_eq!((r[0].0, r[0].1, r[0].2.as_slice()), (1, 0, &[0xFC, 0x03, 48][..]));
    // Return Delay Time 100 µs after the instruction's end.
    assert_eq!(r[0].3, SimInstant::ZERO + Duration::from_micros(100));
    assert_eq!(error_of(&mut c, &write(1, addr::LED, &[1])), 0);
    let r = exchange(&mut c, SimInstant::ZERO, &read(1, addr::MODEL_NUMBER, 2));
    assert_eq!(r[0].2, vec![0xFC, 0x03]);
    // Packets for other IDs get no answer.
    assert!(exchange(&mut c, SimInstant::ZERO, &instruction(2, inst::PING, &[])).is_empty());
}

#[test]
fn table_rules_give_the_manual_error_numbers() {
    let mut c = chain(&[1, 3]);
    // Read-only field: access error.
    assert_eq!(
        error_of(&mut c, &write(1, addr::MODEL_NUMBER, &[1, 2])),
        status::ACCESS
    );
    // Half of a 4-byte field: data length error.
    assert_eq!(
        error_of(&mut c, &write(1, addr::GOAL_POSITION, &[0, 8])),
        status::DATA_LENGTH
    );
    // Operating mode 2 does not exist: data range error.
    assert_eq!(
        error_of(&mut c, &write(1, addr::OPERATING_MODE, &[2])),
        status::DATA_RANGE
    );
    // XL430 has no current modes, and no Goal Current field.
    assert_eq!(
        error_of(&mut c, &write(3, addr::OPERATING_MODE, &[5])),
        status::DATA_RANGE
    );
    assert_eq!(
        error_of(&mut c, &write(3, addr::GOAL_CURRENT, &[0, 0])),
        status::ACCESS
    );
    // Goal beyond Max Position Limit (position mode): data limit error.
    assert_eq!(
        error_of(&mut c, &write(1, addr::GOAL_POSITION, &5000i32.to_le_bytes())),
        status::DATA_LIMIT
    );
    // EEPROM with torque on: access error, and the value is unchanged.
    assert_eq!(error_of(&mut c, &write(1, addr::TORQUE_ENABLE, &[1])), 0);
    assert_eq!(
        error_of(&mut c, &write(1, addr::OPERATING_MODE, &[4])),
        status::ACCESS
    );
    assert_eq!(c.servos()[0].register(addr::OPERATING_MODE), 3);
    // Reads beyond the table: data range error.
    assert_eq!(error_of(&mut c, &read(1, 250, 10)), status::DATA_RANGE);
}

#[test]
fn malformed_packets_get_the_specified_answer_or_none() {
    let mut c = chain(&[1]);
    // Unknown instruction: instruction error.
    assert_eq!(error_of(&mut c, &instruction(1, 0x7E, &[])), status::INSTRUCTION);
    // Action without a registered write: instruction error.
    assert_eq!(
        error_of(&mut c, &instruction(1, inst::ACTION, &[])),
        status::INSTRUCTION
    );
    // Read with three parameter bytes: data length error.
    assert_eq!(
        error_of(&mut c, &instruction(1, inst::READ, &[132, 0, 4])),
        status::DATA_LENGTH
    );
    // Bad CRC: CRC error from the addressed servo.
    let mut bad = read(1, addr::PRESENT_POSITION, 4);
    let n = bad.len();
    bad[n - 1] ^= 0xFF;
    assert_eq!(error_of(&mut c, &bad), status::CRC);
    // Truncated packet, then garbage, then a good ping: only the ping is answered.
    let mut stream = read(1, addr::PRESENT_POSITION, 4);
    stream.truncate(7);
    stream.extend_from_slice(&[0x00, 0x13, 0xFF, 0xFF, 0x42]);
    let r = exchange(&mut c, SimInstant::ZERO, &stream);
    assert!(r.iter().all(|(_, e, _, _)| *e == status::CRC), "{r:?}");
    let r = exchange(&mut c, SimInstant::ZERO, &instruction(1, inst::PING, &[]));
    assert_eq!(
        r.last().map(|p| (p.1, p.2.clone())),
        Some((0, vec![0xFC, 0x03, 48]))
    );
    // A length field below the minimum is dropped without an answer.
    let r = exchange(
        &mut c,
        SimInstant::ZERO,
        &[0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x02, 0x00, 0x01, 0x00, 0x00],
    );
    assert!(r.is_empty());
    assert!(c.stats().crc_errors >= 1 && c.stats().malformed >= 1);
}

#[test]
fn reg_write_waits_for_action_and_status_return_level_silences_answers() {
    let mut c = chain(&[1]);
    let mut p = addr::LED.to_le_bytes().to_vec();
    p.push(1);
    assert_eq!(error_of(&mut c, &instruction(1, inst::REG_WRITE, &p)), 0);
    assert_eq!(c.servos()[0].register(addr::LED), 0);
    assert_eq!(c.servos()[0].register(addr::REGISTERED_INSTRUCTION), 1);
    assert!(
        exchange(
            &mut c,
            SimInstant::ZERO,
            &instruction(BROADCAST_ID, inst::ACTION, &[])
        )
        .is_empty()
    );
    assert_eq!(c.servos()[0].register(addr::LED), 1);
    // Level 1: reads and pings answered, writes silent. Level 0: only pings.
    assert_eq!(error_of(&mut c, &write(1, addr::STATUS_RETURN_LEVEL, &[1])), 0);
    assert!(exchange(&mut c, SimInstant::ZERO, &write(1, addr::LED, &[0])).is_empty());
    assert_eq!(
        exchange(&mut c, SimInstant::ZERO, &read(1, addr::LED, 1)).len(),
        1
    );
    assert_eq!(
        exchange(&mut c, SimInstant::ZERO, &read(1, addr::STATUS_RETURN_LEVEL, 1))[0].2,
        [1]
    );
    assert!(
        exchange(
            &mut c,
            SimInstant::ZERO,
            &write(1, addr::STATUS_RETURN_LEVEL, &[0])
        )
        .is_empty()
    );
    assert!(exchange(&mut c, SimInstant::ZERO, &read(1, addr::LED, 1)).is_empty());
    assert_eq!(
        exchange(&mut c, SimInstant::ZERO, &instruction(1, inst::PING, &[])).len(),
        1
    );
}

#[test]
fn sync_and_bulk_reads_answer_in_list_order_one_after_another() {
    let mut c = chain(&[1, 2, 3]);
    let t0 = SimInstant::ZERO;
    let r = exchange(
        &mut c,
        t0,
        &instruction(BROADCAST_ID, inst::SYNC_READ, &[0, 0, 2, 0, 3, 1, 2]),
    );
    assert_eq!(r.iter().map(|p| p.0).collect::<Vec<_>>(), vec![3, 1, 2]);
    assert_eq!(r[0].2, 1060u16.to_le_bytes());
    // Each status packet (11 + 2 bytes) starts a return delay after the previous one ends.
    let wire = WireTiming::new(BAUD).bytes_time(13);
    assert_eq!(r[1].3, r[0].3 + wire + Duration::from_micros(100));
    // Bulk read: different addresses per servo.
    let bulk = [2, 7, 0, 1, 0, 1, 0, 0, 2, 0];
    let r = exchange(&mut c, t0, &instruction(BROADCAST_ID, inst::BULK_READ, &bulk));
    assert_eq!(
        (r[0].0, r[0].2.clone(), r[1].0, r[1].2.clone()),
        (2, vec![2], 1, vec![0xFC, 0x03])
    );
    // Sync write reaches every listed servo without answers.
    let sw = [65, 0, 1, 0, 1, 1, 3, 1];
    assert!(exchange(&mut c, t0, &instruction(BROADCAST_ID, inst::SYNC_WRITE, &sw)).is_empty());
    assert_eq!([0, 1, 2].map(|i| c.servos()[i].register(addr::LED)), [1, 0, 1]);
    // Broadcast ping: everyone, in ID order.
    let r = exchange(&mut c, t0, &instruction(BROADCAST_ID, inst::PING, &[]));
    assert_eq!(r.iter().map(|p| p.0).collect::<Vec<_>>(), vec![1, 2, 3]);
}

#[test]
fn reboot_and_factory_reset_restore_what_the_manual_says() {
    let mut c = chain(&[5]);
    assert_eq!(error_of(&mut c, &write(5, addr::RETURN_DELAY_TIME, &[10])), 0);
    assert_eq!(error_of(&mut c, &write(5, addr::LED, &[1])), 0);
    assert_eq!(error_of(&mut c, &instruction(5, inst::REBOOT, &[])), 0);
    // Booting: silent.
    assert!(exchange(&mut c, SimInstant::ZERO, &instruction(5, inst::PING, &[])).is_empty());
    let later = SimInstant::ZERO + Duration::from_millis(200);
    assert_eq!(exchange(&mut c, later, &instruction(5, inst::PING, &[])).len(), 1);
    // EEPROM kept, RAM reset.
    assert_eq!(c.servos()[0].register(addr::RETURN_DELAY_TIME), 10);
    assert_eq!(c.servos()[0].register(addr::LED), 0);
    // Factory reset keeping the ID (0x01) restores Return Delay Time 250.
    assert_eq!(
        exchange(&mut c, later, &instruction(5, inst::FACTORY_RESET, &[0x01]))[0].1,
        0
    );
    assert_eq!(c.servos()[0].register(addr::RETURN_DELAY_TIME), 50);
    assert_eq!(c.servos()[0].id(), 5);
}

#[test]
fn random_bytes_never_panic_and_the_servo_still_answers_afterwards() {
    let mut c = chain(&[1, 2]);
    let mut rng = SimRng::new(7);
    let mut t = SimInstant::ZERO;
    let good = read(2, addr::PRESENT_POSITION, 4);
    for _ in 0..3000 {
        let n = (rng.next_u64() % 40) as usize;
        let mut bytes: Vec<u8> = (0..n).map(|_| rng.next_u64() as u8).collect();
        // Sometimes splice in a real header or a real packet, to reach deeper states.
        match rng.next_u64() % 4 {
            0 => bytes.extend_from_slice(&packet::HEADER),
            1 => bytes.extend_from_slice(&good[..(rng.next_u64() as usize % good.len())]),
            _ => {}
        }
        t = t + Duration::from_micros(200);
        c.receive(&bytes, t);
        c.take_replies_due(t + Duration::from_secs(1), &mut |_, _| {});
    }
    // After an idle line (the firmware's packet timeout) the servo answers a good packet.
    let t = t + Duration::from_millis(500);
    let r = exchange(&mut c, t, &good);
    assert!(
        r.iter().any(|p| p.0 == 2 && p.1 & 0x7F == 0 && p.2.len() == 4),
        "{r:?}"
    );
}
