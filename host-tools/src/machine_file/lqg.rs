//! The LQG law of servo joints in a machine file: `servo = { law = "lqg", .. }` runs
//! the design in `lqg_gains = { .. }` (the gains, as `contour-study --design-lqg`
//! prints them) in place of the PID; `lqg = { .. }` holds the weights the design came
//! from ([`crate::control::lqg::LqgWeights`]). With `lqg`, `lqg_gains` and a `plant`, the
//! gains must be the design of that plant and those weights, to 1e-5 of each array's
//! largest value (not bit for bit: `f64::powi` in the matrix exponential may round
//! differently between builds): a file whose plant or weights were edited without
//! designing again is refused.
//!
//! The design is checked on `lqg_model = { num = [..], den = [..] }` instead of the
//! plant when the file has one: the model the gains were designed on, as `nc-send
//! tune --write` writes it (the model it identified from the joint's response), where
//! `plant` stays what it was (in the simulator, the true plant the tune did not know).
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

/// `lqg_model = { .. }`: the transfer function an LQG design was made on, mm or
/// degrees per command unit, coefficients highest power of s first.
#[derive(Clone, Debug, serde::Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LqgModel {
    /// Numerator.
    pub num: Vec<f64>,
    /// Denominator.
    pub den: Vec<f64>,
}

impl LqgModel {
    /// `tf` as an `lqg_model = { .. }` inline table (every coefficient in the shortest
    /// digits that read back to it).
    pub fn toml(tf: &TransferFunction) -> String {
        let list = |xs: &[f64]| {
            let items: Vec<String> = xs.iter().map(|x| format!("{x:e}")).collect();
            format!("[{}]", items.join(", "))
        };
        format!("{{ num = {}, den = {} }}", list(&tf.num), list(&tf.den))
    }
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
        let model = match (&jf.lqg_model, &jf.plant) {
            (Some(m), _) => Some((&m.num, &m.den, "lqg_model", "lqg_model")),
            (None, Some(p)) => Some((&p.num, &p.den, "plant", "plant")),
            (None, None) => None,
        };
        if jf.lqg_model.is_some() && jf.lqg.is_none() {
            return Err(refused!(
                "{}: a model to check the LQG design on needs the design's weights (lqg)",
                f("lqg_model")
            ));
        }
        if let (Some(w), Some((num, den, field, name))) = (&jf.lqg, model) {
            let tf = TransferFunction::new(num, den).map_err(|e| refused!("{}: {e}", f(field)))?;
            let d = design(&tf, jf.steps_per_unit, SERVO_PERIOD_S as f64, w)
                .map_err(|e| refused!("{}: {e}", f("lqg")))?;
            if !close(&d.gains, &g) {
                return Err(refused!(
                    "{}: not the design of this joint's {name} and lqg weights (run \
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
    fn gains_designed_on_an_lqg_model_are_checked_on_it_and_not_on_the_plant() {
        use crate::control::lqg::{design, gains_toml};
        use crate::control::plant::TransferFunction;
        // leg1 with a model 5 % off its plant, as a tune might identify it, and the
        // file's own weights.
        let model =
            TransferFunction::new(&[0.1479, 3.161, 312.7], &[1.0, 18.79, 1142.0, 651.2]).unwrap();
        let file = super::super::read_file(HEXAPOD_XY_MACHINE, "hexapod-xy.toml").unwrap();
        let w = file.joints[0].lqg.unwrap();
        let g = design(&model, 100_000.0, 1e-4, &w).unwrap().gains;
        let leg1 = HEXAPOD_XY_MACHINE.find("name = \"leg1\"").unwrap();
        let (head, tail) = HEXAPOD_XY_MACHINE.split_at(leg1);
        let at = tail.find("\nlqg_gains = ").unwrap();
        let end = at + 1 + tail[at + 1..].find('\n').unwrap();
        let with = |extra: &str| {
            format!(
                "{head}{}\nlqg_gains = {}{extra}{}",
                &tail[..at],
                gains_toml(&g),
                &tail[end..]
            )
        };
        // On the plant those gains are not the design.
        let e = parse(&with(""), "m.toml").unwrap_err().to_string();
        assert!(
            e.contains("joints[0] (leg1).lqg_gains: not the design of this joint's plant"),
            "{e}"
        );
        // With the model they are (and leg1 now has a design of its own).
        let m = parse(
            &with("\nlqg_model = { num = [0.1479, 3.161, 312.7], den = [1, 18.79, 1142, 651.2] }"),
            "m.toml",
        )
        .unwrap();
        assert_eq!(m.servo.lqg.len(), 2);
        assert_eq!(m.servo.lqg[m.servo.law[0] as usize - 1], g);
        // Another model is refused by its name.
        let e = parse(
            &with("\nlqg_model = { num = [0.1479, 3.161, 297.8], den = [1, 18.79, 1142, 651.2] }"),
            "m.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("not the design of this joint's lqg_model"),
            "{e}"
        );
        // A model without the weights it was designed with says nothing.
        let text = with("\nlqg_model = { num = [1], den = [1, 1] }");
        let text = text.replacen("\nlqg = {", "\n# lqg = {", 1);
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(
            e.contains("joints[0] (leg1).lqg_model: a model to check"),
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
