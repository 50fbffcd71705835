//! A rigid rotor behind the scripted telemetry of the commissioning and supervisor
//! tests: what the motion's identification (`drive::spin`) needs to see.

/// J/kt (A·s²/rad), B/kt (A·s/rad), ψ (Wb) of the scripted rotor, and the spin-up's
/// current (A).
pub const AMPS_PER_ACCEL: f32 = 2e-3;
pub const AMPS_PER_SPEED: f32 = 1e-3;
pub const FLUX_WB: f32 = 0.02;
pub const SPIN_UP_A: f32 = 2.0;

/// θ (wrapped), ω and the control period's running integrals (`∫iq dt`, and `∫|v|/p dt`
/// of the back-EMF, which the control period integrates only while coasting; the tests
/// take differences over the coast only, so it runs all along here).
#[derive(Clone, Copy, Debug, Default)]
pub struct Rotor {
    pub theta_rad: f32,
    pub omega_rad_s: f32,
    pub iq_integral_a_s: f32,
    pub flux_angle_wb_rad: [f32; 2],
}

pub enum Drive {
    /// Driven toward this speed against the friction, at [`SPIN_UP_A`] at most.
    Speed(f32),
    /// At this q current (A), open loop in speed (SpinUp's torque probe).
    Torque(f32),
    /// No torque: the friction slows it.
    Coast,
    /// At the speed it has (the application's loop holds it).
    Hold,
}

impl Rotor {
    pub fn step(&mut self, dt_s: f32, drive: Drive) {
        match drive {
            Drive::Speed(target) => {
                // The current that reaches the target this step, at most SPIN_UP_A.
                let friction = AMPS_PER_SPEED * self.omega_rad_s;
                let wanted = AMPS_PER_ACCEL * (target - self.omega_rad_s) / dt_s + friction;
                let iq = wanted.clamp(-SPIN_UP_A, SPIN_UP_A);
                self.omega_rad_s += (iq - friction) / AMPS_PER_ACCEL * dt_s;
                self.iq_integral_a_s += iq * dt_s;
            }
            Drive::Torque(iq) => {
                let friction = AMPS_PER_SPEED * self.omega_rad_s;
                self.omega_rad_s += (iq - friction) / AMPS_PER_ACCEL * dt_s;
                self.iq_integral_a_s += iq * dt_s;
            }
            Drive::Coast => {
                self.omega_rad_s -= AMPS_PER_SPEED * self.omega_rad_s / AMPS_PER_ACCEL * dt_s;
            }
            Drive::Hold => {}
        }
        // The back-EMF on q: the frame is the rotor's.
        self.flux_angle_wb_rad[1] += FLUX_WB * self.omega_rad_s * dt_s;
        self.theta_rad =
            (self.theta_rad + self.omega_rad_s * dt_s).rem_euclid(std::f32::consts::TAU);
    }
}
