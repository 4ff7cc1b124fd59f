//! The bridge's 1 kHz control law: the device position drives a speed setpoint that tracks it
//! (position → velocity, since the server takes speeds), and the rendered force is the
//! server's axial reaction, low-pass filtered and held between server updates, plus a
//! virtual-coupling spring on the tracking error that answers at once, before the server
//! state catches up. Forces fade out when the server state goes stale.

/// Tuning of one axis (insertion: mm, N; rotation: deg, N·mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisGains {
    /// Setpoint speed per unit of tracking error (1/s).
    pub tracking_per_s: f64,
    /// Largest speed setpoint (unit/s).
    pub max_speed: f64,
    /// Virtual-coupling stiffness (force per unit of error).
    pub coupling_stiffness: f64,
    /// Largest rendered force (device limit).
    pub max_force: f64,
}

/// The whole law.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CouplingSettings {
    /// Insertion axis (mm, mm/s, N/mm, N).
    pub insertion: AxisGains,
    /// Rotation axis (deg, deg/s, N·mm/deg, N·mm).
    pub rotation: AxisGains,
    /// Cut-off of the first-order filter on the server's reaction (Hz).
    pub filter_cutoff_hz: f64,
    /// Server state older than this fades the force out (s).
    pub stale_after_s: f64,
    /// Fade-out time constant (s).
    pub fade_s: f64,
}

impl Default for CouplingSettings {
    fn default() -> Self {
        Self {
            insertion: AxisGains {
                tracking_per_s: 25.0,
                max_speed: 100.0,
                coupling_stiffness: 0.02,
                max_force: 4.0,
            },
            rotation: AxisGains {
                tracking_per_s: 25.0,
                max_speed: 720.0,
                coupling_stiffness: 0.05,
                max_force: 50.0,
            },
            filter_cutoff_hz: 40.0,
            stale_after_s: 0.1,
            fade_s: 0.05,
        }
    }
}

/// The latest server state, as the law needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServerSample {
    /// Inserted length (mm).
    pub inserted_mm: f64,
    /// Twist (deg).
    pub twist_deg: f64,
    /// Axial reaction (N, + resists a push).
    pub axial_force_n: f64,
    /// Torque about the axis (N·mm).
    pub axial_torque_nmm: f64,
    /// Age when used (s).
    pub age_s: f64,
}

/// What one tick produces.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Output {
    /// Push/pull speed for the server (mm/s).
    pub push_mm_s: f64,
    /// Twist rate for the server (deg/s).
    pub twist_deg_s: f64,
    /// Force for the device (N).
    pub force_n: f64,
    /// Torque for the device (N·mm).
    pub torque_nmm: f64,
    /// The server state was fresh.
    pub live: bool,
}

/// The law's state.
#[derive(Debug, Clone)]
pub struct Coupling {
    settings: CouplingSettings,
    /// Device position + offset = the inserted length it asks for (set when engaging).
    offset: Option<(f64, f64)>,
    filtered_force: f64,
    filtered_torque: f64,
    fade: f64,
    last: Output,
}

impl Coupling {
    /// A disengaged law (no offset yet).
    pub fn new(settings: CouplingSettings) -> Self {
        Self {
            settings,
            offset: None,
            filtered_force: 0.0,
            filtered_torque: 0.0,
            fade: 0.0,
            last: Output::default(),
        }
    }

    /// Forgets the clutch (a new session: the device engages where the new device is).
    pub fn disengage(&mut self) {
        self.offset = None;
        self.filtered_force = 0.0;
        self.filtered_torque = 0.0;
        self.fade = 0.0;
    }

    /// One tick of `dt_s` with the device at (`insertion_mm`, `rotation_deg`) and the latest
    /// server state, if any.
    pub fn update(
        &mut self,
        dt_s: f64,
        insertion_mm: f64,
        rotation_deg: f64,
        server: Option<ServerSample>,
    ) -> Output {
        let s = self.settings;
        let Some(server) = server else {
            self.fade_out(dt_s);
            self.last = Output {
                force_n: self.filtered_force * self.fade,
                torque_nmm: self.filtered_torque * self.fade,
                ..Output::default()
            };
            return self.last;
        };
        // Clutch: the device engages at the simulated device's current position.
        let (x0, a0) = *self.offset.get_or_insert((
            server.inserted_mm - insertion_mm,
            server.twist_deg - rotation_deg,
        ));
        // Where the simulated device is now: the last state moved on by the last setpoint.
        let lead = server.age_s.min(s.stale_after_s);
        let x_sim = server.inserted_mm + self.last.push_mm_s * lead;
        let a_sim = server.twist_deg + self.last.twist_deg_s * lead;
        let x_err = insertion_mm + x0 - x_sim;
        let a_err = rotation_deg + a0 - a_sim;
        let live = server.age_s <= s.stale_after_s;
        // First-order low-pass on the server's reaction (exact discretisation: stable for any
        // dt), held between updates by construction.
        let alpha = 1.0 - (-2.0 * std::f64::consts::PI * s.filter_cutoff_hz * dt_s).exp();
        if live {
            self.filtered_force += alpha * (server.axial_force_n - self.filtered_force);
            self.filtered_torque += alpha * (server.axial_torque_nmm - self.filtered_torque);
            self.fade = (self.fade + dt_s / s.fade_s).min(1.0);
        } else {
            self.fade_out(dt_s);
        }
        let spring = |gains: AxisGains, err: f64| gains.coupling_stiffness * err;
        let clamp = |v: f64, limit: f64| v.clamp(-limit, limit);
        self.last = Output {
            push_mm_s: if live {
                clamp(s.insertion.tracking_per_s * x_err, s.insertion.max_speed)
            } else {
                0.0
            },
            twist_deg_s: if live {
                clamp(s.rotation.tracking_per_s * a_err, s.rotation.max_speed)
            } else {
                0.0
            },
            force_n: clamp(
                self.fade * (self.filtered_force + spring(s.insertion, x_err)),
                s.insertion.max_force,
            ),
            torque_nmm: clamp(
                self.fade * (self.filtered_torque + spring(s.rotation, a_err)),
                s.rotation.max_force,
            ),
            live,
        };
        self.last
    }

    fn fade_out(&mut self, dt_s: f64) {
        self.fade = (self.fade - dt_s / self.settings.fade_s).max(0.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(inserted_mm: f64, force: f64, age_s: f64) -> ServerSample {
        ServerSample {
            inserted_mm,
            twist_deg: 0.0,
            axial_force_n: force,
            axial_torque_nmm: 0.0,
            age_s,
        }
    }

    #[test]
    fn the_setpoint_tracks_the_device_from_where_it_engaged() {
        let mut c = Coupling::new(CouplingSettings::default());
        // Engages with the device at 5 mm and the simulated wire at 40 mm: no jump.
        let out = c.update(1e-3, 5.0, 0.0, Some(sample(40.0, 0.0, 0.0)));
        assert_eq!(out.push_mm_s, 0.0);
        // The hand moves 1 mm: the setpoint is 25 mm/s per mm of error.
        let out = c.update(1e-3, 6.0, 0.0, Some(sample(40.0, 0.0, 0.0)));
        assert!((out.push_mm_s - 25.0).abs() < 1e-12);
        // A big move saturates at the speed limit.
        let out = c.update(1e-3, 100.0, 0.0, Some(sample(40.0, 0.0, 0.0)));
        assert_eq!(out.push_mm_s, 100.0);
    }

    #[test]
    fn simulated_tracking_converges_and_the_filter_reaches_the_server_force() {
        // A server that integrates the setpoint at 500 Hz, state 2 ms late, with a constant
        // reaction of 0.3 N: the wire follows a 10 mm hand move within 0.2 s and the force
        // settles on 0.3 N with no overshoot beyond the spring's share.
        let mut c = Coupling::new(CouplingSettings::default());
        let (mut sim_x, mut hand) = (0.0, 0.0);
        let mut state = sample(0.0, 0.3, 0.0);
        let mut peak: f64 = 0.0;
        let mut out = Output::default();
        for tick in 0..1000 {
            if tick == 10 {
                hand = 10.0;
            }
            if tick % 2 == 0 {
                state = sample(sim_x, 0.3, 0.002);
                sim_x += out.push_mm_s * 0.002;
            }
            out = c.update(1e-3, hand, 0.0, Some(state));
            peak = peak.max(out.force_n);
            if tick == 250 {
                assert!((sim_x - 10.0).abs() < 0.05, "followed to {sim_x}");
            }
        }
        assert!(
            (out.force_n - 0.3).abs() < 0.01,
            "settled at {}",
            out.force_n
        );
        assert!(peak <= 0.3 + 0.02 * 10.0 + 1e-9, "peak {peak}");
    }

    #[test]
    fn the_filter_is_stable_and_holds_between_updates() {
        // A server force that jumps between 0 and 1 N every update: the rendered force stays
        // within the input's range (a first-order filter cannot overshoot).
        let mut c = Coupling::new(CouplingSettings::default());
        for tick in 0..2000 {
            let f = if (tick / 2) % 2 == 0 { 1.0 } else { 0.0 };
            let out = c.update(1e-3, 0.0, 0.0, Some(sample(0.0, f, 0.001)));
            assert!(
                (-1e-12..=1.0 + 1e-12).contains(&out.force_n),
                "{}",
                out.force_n
            );
        }
    }

    #[test]
    fn stale_or_missing_server_state_stops_the_device_and_fades_the_force() {
        let mut c = Coupling::new(CouplingSettings::default());
        for _ in 0..200 {
            c.update(1e-3, 0.0, 0.0, Some(sample(0.0, 1.0, 0.0)));
        }
        let stale = c.update(1e-3, 3.0, 0.0, Some(sample(0.0, 1.0, 0.5)));
        assert_eq!(stale.push_mm_s, 0.0);
        assert!(!stale.live);
        let mut force = stale.force_n;
        for _ in 0..60 {
            force = c.update(1e-3, 3.0, 0.0, None).force_n;
        }
        assert_eq!(force, 0.0, "faded out after the fade time");
    }

    #[test]
    fn forces_saturate_at_the_device_limit() {
        let mut c = Coupling::new(CouplingSettings::default());
        for _ in 0..500 {
            c.update(1e-3, 0.0, 0.0, Some(sample(0.0, 50.0, 0.0)));
        }
        let out = c.update(1e-3, 0.0, 0.0, Some(sample(0.0, 50.0, 0.0)));
        assert_eq!(out.force_n, 4.0);
    }
}
