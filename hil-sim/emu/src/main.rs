fn main() -> anyhow::Result<()> {
    let elf = std::fs::read("target/thumbv7em-none-eabihf/release/drive-fw")?;
    let board = drive_emu::board::Board::commissioning(1)?;
    let mut emu = drive_emu::Emu::new(&elf, board, None)?;
    let t0 = std::time::Instant::now();
    for k in 1..=30 {
        emu.run_until(k as f64 * 0.1)?;
        let m = emu.m();
        eprintln!(
            "t={:.1} instrs={} pc={:#x} isr={} mean={:.0} max={} masked={} missed={} trig={} boots={} faults={:?} gated={:?} unknown={} rtt={}B theta={:.2} w={:.1}",
            m.time_s(), m.instrs, emu.pc(), m.stats.isr_count, m.stats.isr_mean(), m.stats.isr_instrs_max,
            m.stats.masked_max, m.adcs.missed_triggers, m.adcs.triggers, m.stats.boots.len(),
            m.stats.hard_faults, m.unmodelled.gated, m.unmodelled.unknown.len(), m.rtt.bytes.len(),
            m.board.truth().theta_rad, m.board.truth().omega_rad_s
        );
    }
    eprintln!("wall {:?}", t0.elapsed());
    let d = hil_sim::stream::decode(&emu.elf, &emu.m().rtt.bytes)?;
    for i in d.items.iter() {
        match i {
            hil_sim::stream::Item::Line(l) if l.kind == "mras" => {}
            hil_sim::stream::Item::Line(l) => eprintln!("{}", l.describe()),
            hil_sim::stream::Item::Other(o) => eprintln!("{o}"),
        }
    }
    Ok(())
}
