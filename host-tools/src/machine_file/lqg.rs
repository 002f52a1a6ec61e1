//! The LQG law of servo joints in a machine file: `servo = { law = "lqg", .. }` runs
//! the design in `lqg_gains = { .. }` (the gains, as `contour-study --design-lqg`
//! prints them) in place of the PID; `lqg = { .. }` holds the weights the design came
//! from ([`crate::control::lqg::LqgWeights`]). With `lqg`, `lqg_gains` and a `plant`, the
//! gains must be the design of that plant and those weights, to 1e-5 of each array's
//! largest value (not bit for bit: `f64::powi` in the matrix exponential may round
//! differently between builds): a file whose plant or weights were edited without
//! designing again is refused.
//!
//! The controller keeps at most [`MAX_LQG`] distinct designs; joints with the same
//! gains (the legs of a hexapod) share one.

use super::{refused, FieldError, MachineFile};
use crate::control::lqg::{design, gains_toml};
use crate::control::plant::TransferFunction;
use pkmc::config::LqgGains;
use pkmc::config::{Drive, MachineConfig, MAX_LQG};
use pkmc::drive::servo::SERVO_PERIOD_S;

/// `servo.law`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LawKind {
    /// The PID of the `servo` table.
    #[default]
    Pid,
    /// The LQG design of `lqg_gains`.
    Lqg,
}

/// Are `a` and `b` the same design, to 1e-5 of each array's largest value?
fn close(a: &LqgGains, b: &LqgGains) -> bool {
    let near = |x: &[f32], y: &[f32]| {
        let scale = x.iter().chain(y).fold(0.0f32, |m, v| m.max(v.abs()));
        x.iter().zip(y).all(|(p, q)| (p - q).abs() <= 1e-5 * scale)
    };
    let phi = |g: &LqgGains| g.phi_minus_i.concat();
    a.order == b.order
        && near(&phi(a), &phi(b))
        && near(&a.gamma, &b.gamma)
        && near(&a.c, &b.c)
        && near(&a.m, &b.m)
        && near(&a.k, &b.k)
        && near(&[a.ki_t], &[b.ki_t])
}

impl MachineFile {
    /// Joint `j`'s LQG gains after checking them against its weights and plant.
    fn checked_gains(&self, j: usize) -> Result<Option<LqgGains>, FieldError> {
        let jf = &self.joints[j];
        let f = |s: &str| format!("joints[{j}] ({}).{s}", jf.name);
        let Some(g) = jf.lqg_gains else {
            return Ok(None);
        };
        if !g.is_valid() {
            return Err(refused!(
                "{}: order must be 1..=4, every value finite, the entries beyond the order \
                 zero and ki_t >= 0",
                f("lqg_gains")
            ));
        }
        if let (Some(w), Some(p)) = (&jf.lqg, &jf.plant) {
            let tf = TransferFunction::new(&p.num, &p.den)
                .map_err(|e| refused!("{}: {e}", f("plant")))?;
            let d = design(&tf, jf.steps_per_unit, SERVO_PERIOD_S as f64, w)
                .map_err(|e| refused!("{}: {e}", f("lqg")))?;
            if !close(&d.gains, &g) {
                return Err(refused!(
                    "{}: not the design of this joint's plant and lqg weights (run \
                     `contour-study --design-lqg --machine FILE`); the design is {}",
                    f("lqg_gains"),
                    gains_toml(&d.gains)
                ));
            }
        }
        Ok(Some(g))
    }

    /// Sets the feedback law of every servo joint of `config` that runs LQG (every
    /// joint with `lqg_gains` when `all`, as a study comparing the laws does): its
    /// design shared with the joints of equal gains.
    pub fn apply_lqg(&self, config: &mut MachineConfig, all: bool) -> Result<(), FieldError> {
        for (j, jf) in self.joints.iter().enumerate() {
            let law = jf.servo.as_ref().map(|s| s.law).unwrap_or_default();
            let gains = self.checked_gains(j)?;
            let wanted = all || law == LawKind::Lqg;
            let Drive::Servo { channel } = config.joints[j].drive else {
                continue;
            };
            let c = channel as usize;
            config.servo.law[c] = 0;
            if !wanted {
                continue;
            }
            let Some(g) = gains else {
                if law == LawKind::Lqg {
                    return Err(refused!(
                        "joints[{j}] ({}).lqg_gains: law = \"lqg\" needs the design's gains \
                         (run `contour-study --design-lqg --machine FILE`)",
                        jf.name
                    ));
                }
                continue;
            };
            let k = match config.servo.lqg.iter().position(|d| *d == g) {
                Some(k) => k,
                None => {
                    config.servo.lqg.push(g).map_err(|_| {
                        refused!(
                            "joints[{j}] ({}).lqg_gains: more than {MAX_LQG} different LQG \
                             designs in one machine",
                            jf.name
                        )
                    })?;
                    config.servo.lqg.len() - 1
                }
            };
            config.servo.law[c] = k as u8 + 1;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::super::{parse, HEXAPOD_XY_MACHINE};

    #[test]
    fn the_legs_share_one_design_and_the_table_keeps_its_pid() {
        let m = parse(HEXAPOD_XY_MACHINE, "hexapod-xy.toml").unwrap();
        assert_eq!(m.servo.lqg.len(), 1);
        assert_eq!(m.servo.law, [1, 1, 1, 1, 1, 1, 0, 0]);
    }

    #[test]
    fn gains_that_are_not_the_design_of_their_weights_are_refused() {
        let text =
            HEXAPOD_XY_MACHINE.replacen("integral_weight = 0.004", "integral_weight = 0.003", 1);
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(
            e.contains("joints[0] (leg1).lqg_gains: not the design of this joint's plant"),
            "{e}"
        );
    }

    #[test]
    fn an_lqg_law_without_gains_names_the_missing_field() {
        let text = HEXAPOD_XY_MACHINE.replacen("\nlqg_gains = {", "\nxlqg_gains = {", 1);
        let text = text.replacen("xlqg_gains", "# lqg_gains", 1);
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(
            e.contains("joints[0] (leg1).lqg_gains: law = \"lqg\" needs"),
            "{e}"
        );
    }

    #[test]
    fn more_designs_than_the_controller_holds_are_refused() {
        // The table's joints on LQG too makes three designs (the limit); a fourth,
        // from a leg with other gains, is one too many (found at the last joint, table Y).
        let mut text =
            HEXAPOD_XY_MACHINE.replace("servo = { kp = 0.1,", "servo = { law = \"lqg\", kp = 0.1,");
        text = text.replace(
            "servo = { kp = 0.075,",
            "servo = { law = \"lqg\", kp = 0.075,",
        );
        assert_eq!(parse(&text, "m.toml").unwrap().servo.lqg.len(), 3);
        let leg6 = text.rfind("name = \"leg6\"").unwrap();
        let (head, tail) = text.split_at(leg6);
        // Other gains, and without weights they are taken as given.
        let tail = tail
            .replacen("ki_t = 6.3061966e-6", "ki_t = 7e-6", 1)
            .replacen("\nlqg = {", "\n# lqg = {", 1);
        let text = format!("{head}{tail}");
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(
            e.contains("joints[7] (table Y).lqg_gains: more than 3 different LQG designs"),
            "{e}"
        );
    }
}
