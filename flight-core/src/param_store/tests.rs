use super::*;
use embedded_storage::nor_flash::{ErrorType, NorFlashError, NorFlashErrorKind, ReadNorFlash};
use std::vec::Vec;

/// A NOR flash in memory, as the STM32F4's behaves: erase sets bytes to 0xFF, a write can only clear bits. It
/// loses power after `budget` byte operations (an erased or a written byte each): from then on nothing changes
/// and every operation fails, as if the board had gone dark in the middle.
struct SimFlash {
    mem: Vec<u8>,
    budget: Option<usize>,
    ops: usize,
}

#[derive(Debug)]
struct PowerCut;

impl NorFlashError for PowerCut {
    fn kind(&self) -> NorFlashErrorKind {
        NorFlashErrorKind::Other
    }
}

impl ErrorType for SimFlash {
    type Error = PowerCut;
}

const SECTOR: usize = 2048;

impl SimFlash {
    fn new() -> Self {
        Self { mem: vec![0xFF; 4 * SECTOR], budget: None, ops: 0 }
    }

    fn step(&mut self) -> Result<(), PowerCut> {
        if self.budget.is_some_and(|b| self.ops >= b) {
            return Err(PowerCut);
        }
        self.ops += 1;
        Ok(())
    }
}

impl ReadNorFlash for SimFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), PowerCut> {
        let o = offset as usize;
        bytes.copy_from_slice(&self.mem[o..o + bytes.len()]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.mem.len()
    }
}

impl NorFlash for SimFlash {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = SECTOR;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), PowerCut> {
        assert!((from as usize).is_multiple_of(SECTOR) && (to as usize).is_multiple_of(SECTOR));
        for i in from as usize..to as usize {
            self.step()?;
            self.mem[i] = 0xFF;
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), PowerCut> {
        assert!(offset.is_multiple_of(4) && bytes.len().is_multiple_of(4), "aligned writes");
        for (i, &b) in bytes.iter().enumerate() {
            self.step()?;
            self.mem[offset as usize + i] &= b;
        }
        Ok(())
    }
}

fn store(flash: SimFlash) -> ParamStore<SimFlash> {
    ParamStore::new(flash, [0, 2 * SECTOR as u32], SECTOR as u32).unwrap()
}

fn set_a() -> FlightConfig {
    let mut p = FlightConfig::paper();
    p.control.trajectory.speed_m_s = 0.25;
    p
}

fn set_b() -> FlightConfig {
    let mut p = FlightConfig::paper();
    p.control.trajectory.speed_m_s = 0.15;
    p.control.trajectory.y_d_m = 1.1;
    // Another line: the stored set is the whole configuration, the vision part included.
    p.vision.target.x_end_m = 2.0;
    p
}

#[test]
fn a_blank_flash_gives_the_defaults_and_saves_alternate_between_the_slots() {
    let mut s = store(SimFlash::new());
    let (p, r) = s.load();
    assert_eq!(p, None);
    assert_eq!(r, LoadReport { slot: None, sequence: 0, problems: [Some(SlotProblem::Empty); 2] });
    assert_eq!(s.save(&set_a()), Ok(1));
    assert_eq!(
        s.load(),
        (
            Some(set_a()),
            LoadReport { slot: Some(0), sequence: 1, problems: [None, Some(SlotProblem::Empty)] }
        )
    );
    assert_eq!(s.save(&set_b()), Ok(2));
    let (p, r) = s.load();
    assert_eq!((p, r.slot, r.sequence), (Some(set_b()), Some(1), 2));
    assert_eq!(s.save(&set_a()), Ok(3));
    assert_eq!(s.load().1.slot, Some(0), "the older slot is the one written");
    // An invalid set is refused before anything is erased, naming its field.
    let mut bad = set_a();
    bad.control.trajectory.speed_m_s = -1.0;
    assert!(matches!(s.save(&bad), Err(StoreError::Invalid(_))));
    // So is one whose vision part is invalid.
    let mut bad = set_a();
    bad.vision.target.x_end_m = -1.0;
    assert_eq!(s.save(&bad), Err(StoreError::Invalid("vision.target")));
    assert_eq!(s.load().0, Some(set_a()));
    // The body of a set fits with room to spare.
    let mut buf = [0u8; MAX_BODY];
    let n = postcard::to_slice(&FlightConfig::paper(), &mut buf).unwrap().len();
    assert!(HEADER_LEN + n < SECTOR, "{n} bytes");
}

#[test]
fn a_power_cut_at_every_step_of_a_save_leaves_the_old_set_or_the_new_one() {
    // How many byte operations a whole save takes.
    let mut s = store(SimFlash::new());
    s.save(&set_a()).unwrap();
    let before = s.into_inner();
    let mut probe = store(SimFlash { mem: before.mem.clone(), budget: None, ops: 0 });
    probe.save(&set_b()).unwrap();
    let total = probe.into_inner().ops;
    assert!(total > SECTOR, "an erase and the writes: {total}");
    eprintln!("a save is {total} byte operations; the power cut after each of them");
    let (mut old, mut new) = (0, 0);
    for cut in 0..=total {
        let mut s = store(SimFlash { mem: before.mem.clone(), budget: Some(cut), ops: 0 });
        let saved = s.save(&set_b());
        assert_eq!(saved.is_ok(), cut == total, "cut after {cut} of {total}");
        // Power comes back: the set is the old one or the new one, never another.
        let flash = s.into_inner();
        let mut s = store(SimFlash { mem: flash.mem, budget: None, ops: 0 });
        let (p, r) = s.load();
        if p == Some(set_a()) {
            old += 1;
            assert_eq!((r.slot, r.sequence), (Some(0), 1));
        } else {
            assert_eq!(p, Some(set_b()), "cut after {cut}: {r:?}");
            assert_eq!(r.sequence, 2);
            new += 1;
        }
        // And the next save works from there.
        let next = s.save(&set_a()).unwrap();
        assert_eq!(s.load().0, Some(set_a()), "after the cut at {cut}, saved as {next}");
    }
    // Only the last operation (the commit word's last byte) makes the new set.
    assert_eq!((old, new), (total, 1));
}

#[test]
fn damage_and_other_layouts_are_named_and_the_other_slot_is_used() {
    let mut s = store(SimFlash::new());
    s.save(&set_a()).unwrap();
    s.save(&set_b()).unwrap();
    let mut flash = s.into_inner();
    let slot1 = 2 * SECTOR;
    // A bit flipped in the newest set's body: its CRC fails, the older set is loaded.
    flash.mem[slot1 + HEADER_LEN + 3] ^= 0x10;
    let mut s = store(flash);
    let (p, r) = s.load();
    assert_eq!((p, r.slot, r.problems[1]), (Some(set_a()), Some(0), Some(SlotProblem::Crc)));
    let mut flash = s.into_inner();
    flash.mem[slot1 + HEADER_LEN + 3] ^= 0x10;
    // Another schema key (a firmware with another parameter layout) and another store format.
    flash.mem[slot1 + 8] ^= 1;
    let mut s = store(flash);
    assert_eq!(s.load().1.problems[1], Some(SlotProblem::Schema));
    let mut flash = s.into_inner();
    flash.mem[slot1 + 8] ^= 1;
    flash.mem[slot1 + 4] = 9;
    let mut s = store(flash);
    assert_eq!(s.load().1.problems[1], Some(SlotProblem::Format));
    // No commit word.
    let mut flash = s.into_inner();
    flash.mem[slot1 + 4] = STORE_FORMAT as u8;
    flash.mem[slot1 + 24..slot1 + 28].fill(0xFF);
    let mut s = store(flash);
    assert_eq!(s.load().1.problems[1], Some(SlotProblem::NotCommitted));
    // Both gone: the defaults, and both reasons.
    let mut flash = s.into_inner();
    flash.mem[0..4].copy_from_slice(b"XXXX");
    let mut s = store(flash);
    let (p, r) = s.load();
    assert_eq!(p, None);
    assert_eq!(r.problems, [Some(SlotProblem::Empty), Some(SlotProblem::NotCommitted)]);
    // A layout that does not fit is refused.
    assert!(matches!(ParamStore::new(SimFlash::new(), [0, 100], SECTOR as u32), Err(StoreError::Layout)));
    assert!(matches!(ParamStore::new(SimFlash::new(), [0, 0], SECTOR as u32), Err(StoreError::Layout)));
    assert!(matches!(
        ParamStore::new(SimFlash::new(), [0, 3 * SECTOR as u32], 2 * SECTOR as u32),
        Err(StoreError::Layout)
    ));
}

/// Writes a whole slot by hand: the header for `len`, `sequence` and `body`, with its CRC and commit word.
fn write_slot(mem: &mut [u8], base: usize, sequence: u32, body: &[u8], len_field: u16) {
    let mut head = [0u8; HEADER_LEN];
    head[0..4].copy_from_slice(&MAGIC);
    head[4..6].copy_from_slice(&STORE_FORMAT.to_le_bytes());
    head[6..8].copy_from_slice(&len_field.to_le_bytes());
    head[8..16].copy_from_slice(&SCHEMA_KEY);
    head[16..20].copy_from_slice(&sequence.to_le_bytes());
    let mut d = CRC32.digest();
    d.update(&head[0..20]);
    d.update(body);
    head[20..24].copy_from_slice(&d.finalize().to_le_bytes());
    head[24..28].copy_from_slice(&COMMIT.to_le_bytes());
    mem[base..base + HEADER_LEN].copy_from_slice(&head);
    mem[base + HEADER_LEN..base + HEADER_LEN + body.len()].copy_from_slice(body);
}

#[test]
fn sequence_numbers_wrap_lengths_are_bounded_and_slots_must_hold_a_set() {
    let mut buf = [0u8; MAX_BODY];
    let a = postcard::to_slice(&set_a(), &mut buf).unwrap().to_vec();
    let b = postcard::to_slice(&set_b(), &mut buf).unwrap().to_vec();
    let slot1 = 2 * SECTOR;
    // Slot 0 at the last sequence number, slot 1 after the wrap: slot 1 is the newer.
    let mut flash = SimFlash::new();
    write_slot(&mut flash.mem, 0, u32::MAX, &a, a.len() as u16);
    write_slot(&mut flash.mem, slot1, 0, &b, b.len() as u16);
    let mut s = store(flash);
    let (p, r) = s.load();
    assert_eq!((p, r.slot, r.sequence), (Some(set_b()), Some(1), 0));
    // And the next save goes to slot 0 with sequence 1.
    assert_eq!(s.save(&set_a()), Ok(1));
    assert_eq!(s.load().1.slot, Some(0));
    // The other way round: slot 0 newer.
    let mut flash = SimFlash::new();
    write_slot(&mut flash.mem, 0, 5, &a, a.len() as u16);
    write_slot(&mut flash.mem, slot1, 4, &b, b.len() as u16);
    assert_eq!(store(flash).load().1.slot, Some(0));
    // A tie goes to slot 0.
    let mut flash = SimFlash::new();
    write_slot(&mut flash.mem, 0, 7, &a, a.len() as u16);
    write_slot(&mut flash.mem, slot1, 7, &b, b.len() as u16);
    assert_eq!(
        store(flash).load(),
        (Some(set_a()), LoadReport { slot: Some(0), sequence: 7, problems: [None, None] })
    );
    // A length beyond MAX_BODY is named; MAX_BODY itself is a length, whose CRC then fails.
    let mut flash = SimFlash::new();
    write_slot(&mut flash.mem, 0, 1, &a, (MAX_BODY + 1) as u16);
    write_slot(&mut flash.mem, slot1, 1, &a, MAX_BODY as u16);
    assert_eq!(store(flash).load().1.problems, [Some(SlotProblem::Length), Some(SlotProblem::Crc)]);
    // A slot smaller than a header and MAX_BODY is refused.
    struct Small;
    impl ErrorType for Small {
        type Error = PowerCut;
    }
    impl ReadNorFlash for Small {
        const READ_SIZE: usize = 1;
        fn read(&mut self, _: u32, _: &mut [u8]) -> Result<(), PowerCut> {
            Ok(())
        }
        fn capacity(&self) -> usize {
            8192
        }
    }
    impl NorFlash for Small {
        const WRITE_SIZE: usize = 1;
        const ERASE_SIZE: usize = 512;
        fn erase(&mut self, _: u32, _: u32) -> Result<(), PowerCut> {
            Ok(())
        }
        fn write(&mut self, _: u32, _: &[u8]) -> Result<(), PowerCut> {
            Ok(())
        }
    }
    assert!(matches!(ParamStore::new(Small, [0, 1024], 1024), Err(StoreError::Layout)));
    assert!(ParamStore::new(Small, [0, 1536], 1536).is_ok());
}
