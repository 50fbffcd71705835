use calib_record::RamFlash;
use drive::commissioning::State;
use hil_sim::rig::{Rig, SimFlash, Step};
use hil_sim::scenario::Scenario;
#[test]
fn scratch_b2() {
    let sc = Scenario::load("commissioning").unwrap();
    let (_, flash) = hil_sim::power_up::boot(
        &sc,
        SimFlash::new(RamFlash::default()),
        sc.file.seed,
        4.0,
        None,
    )
    .unwrap();
    let mut rig = hil_sim::power_up::rig(&sc, flash, sc.file.seed + 1).unwrap();
    let mut n = 0u64;
    let mut hook = |rig: &mut Rig, s: &Step| {
        if rig.supervisor().map(|x| x.state()) == Some(State::Identify) {
            n += 1;
            if n % 200 == 0 {
                let [ia, ib] = rig.plant.currents_ab();
                println!(
                    "t {:.3} th {:.5} w {:.4} i ({:+.3},{:+.3}) xy ({:.4},{:.4})",
                    s.truth.t_s,
                    s.truth.theta_rad,
                    s.truth.omega_rad_s,
                    ia,
                    ib,
                    s.input.0,
                    s.input.1
                );
            }
        }
    };
    let b = hil_sim::power_up::run_boot(&mut rig, &sc, 0.5, Some(&mut hook));
    println!("{:?}", b.transitions);
}
