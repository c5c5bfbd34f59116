//! The extruder board: configures a Klipper MCU for one stepper and one hot end and runs them.
//!
//! Configuration follows Klipper's sequence: `get_config`; if the MCU is unconfigured, send
//! `allocate_oids`, the `config_*` commands and `finalize_config crc` where crc is the CRC-32 of
//! the configuration text, so that on a reconnect the host can tell (from `get_config`'s crc)
//! whether the MCU still holds the same configuration or needs a firmware restart.
//!
//! While running, [`ExtruderBoard::poll`] turns ADC reports into temperatures, checks the heater
//! (range and verify_heater) and sends a new heater duty per report, scheduled slightly ahead so it
//! arrives before its clock; the MCU turns the heater off by itself if those updates stop
//! (max_duration). Steps from [`ExtruderBoard::sample`] are compressed and sent when their time
//! comes within the lead time of the MCU clock.

use crate::config::BoardConfig;
use crate::dictionary::Value;
use crate::mcu::{ConnectOptions, Mcu, McuError, crc32};
use crate::stepcompress::{StepCmd, StepCompress, StepGenerator};
use crate::thermal::{HeaterCheck, Pid, Thermistor};

const STEPPER_OID: u8 = 0;
const HEATER_OID: u8 = 1;
const ADC_OID: u8 = 2;
const ENABLE_OID: u8 = 3;

const QUEUE_STEP: &str = "queue_step oid=%c interval=%u count=%hu add=%hi";
const SET_DIR: &str = "set_next_step_dir oid=%c dir=%c";
const RESET_CLOCK: &str = "reset_step_clock oid=%c clock=%u";
const QUEUE_PWM: &str = "queue_pwm_out oid=%c clock=%u value=%hu";

/// One temperature reading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    /// Host time of the sample, s.
    pub time: f64,
    /// Temperature, °C.
    pub temp: f64,
    /// Heater duty set in response, 0..1.
    pub duty: f64,
}

/// A configured extruder board.
#[derive(Debug)]
pub struct ExtruderBoard {
    /// The MCU connection.
    pub mcu: Mcu,
    cfg: BoardConfig,
    sc: StepCompress,
    gen_: StepGenerator,
    thermistor: Thermistor,
    pid: Pid,
    check: HeaterCheck,
    /// Hot-end target, °C (0 = off).
    pub target: f64,
    /// Readings since the last call to [`ExtruderBoard::take_readings`].
    readings: Vec<Reading>,
    /// Latest reading.
    pub last: Option<Reading>,
    /// Heater fault (host-detected), once any.
    pub fault: Option<String>,
    adc_scale: f64,
    pwm_max: f64,
    /// Whether the heater is refreshed by poll (tests switch it off to provoke max_duration).
    pub refresh_heater: bool,
    /// The configuration CRC sent with finalize_config.
    pub config_crc: u32,
    /// Steps sent (count).
    pub steps_sent: u64,
    pending_cmds: Vec<StepCmd>,
}

fn fmt_args(name: &str, args: &[(&str, Value)]) -> String {
    let mut s = name.to_string();
    for (k, v) in args {
        let v = match v {
            Value::Int(i) => i.to_string(),
            Value::Enum(e) => e.clone(),
            Value::Bytes(b) => format!("{b:?}"),
        };
        s.push_str(&format!(" {k}={v}"));
    }
    s
}

impl ExtruderBoard {
    /// Connects, identifies, syncs the clock and configures the board.
    pub fn connect(cfg: BoardConfig, opts: ConnectOptions) -> Result<Self, McuError> {
        let mcu = Mcu::connect(&cfg.serial, cfg.baud, opts)?;
        let freq = mcu.clock_freq();
        let adc_max = mcu.dict.constant_f64("ADC_MAX")?;
        let pwm_max = mcu.dict.constant_f64("PWM_MAX")?;
        let thermistor = crate::config::thermistor(&cfg);
        let mut b = Self {
            sc: StepCompress::new((cfg.max_step_error * freq) as u64),
            gen_: StepGenerator::new(cfg.full_steps_per_rotation, cfg.microsteps, cfg.rotation_distance),
            pid: Pid::new(cfg.pid_kp, cfg.pid_ki, cfg.pid_kd, cfg.max_power, cfg.smooth_time),
            check: {
                let mut c = HeaterCheck::new(cfg.min_temp, cfg.max_temp);
                (c.hysteresis, c.max_error, c.heating_gain, c.check_gain_time) =
                    (cfg.hysteresis, cfg.max_error, cfg.heating_gain, cfg.check_gain_time);
                c
            },
            thermistor,
            target: 0.0,
            readings: Vec::new(),
            last: None,
            fault: None,
            adc_scale: adc_max * f64::from(cfg.sample_count),
            pwm_max,
            refresh_heater: true,
            config_crc: 0,
            steps_sent: 0,
            pending_cmds: Vec::new(),
            mcu,
            cfg,
        };
        b.configure()?;
        Ok(b)
    }

    fn configure(&mut self) -> Result<(), McuError> {
        let freq = self.mcu.clock_freq();
        let c = &self.cfg;
        let ticks = |s: f64| Value::Int((s * freq).round() as i64);
        let pin = |p: &str| Value::Enum(p.to_string());
        let mut cmds: Vec<(&str, Vec<(&str, Value)>)> = vec![
            (
                "config_stepper oid=%c step_pin=%c dir_pin=%c invert_step=%c step_pulse_ticks=%u",
                vec![
                    ("oid", Value::Int(STEPPER_OID.into())),
                    ("step_pin", pin(&c.step_pin)),
                    ("dir_pin", pin(&c.dir_pin)),
                    ("invert_step", Value::Int(0)),
                    ("step_pulse_ticks", ticks(c.step_pulse_duration)),
                ],
            ),
            (
                "config_pwm_out oid=%c pin=%u cycle_ticks=%u value=%hu default_value=%hu max_duration=%u",
                vec![
                    ("oid", Value::Int(HEATER_OID.into())),
                    ("pin", pin(&c.heater_pin)),
                    ("cycle_ticks", ticks(c.pwm_cycle_time)),
                    ("value", Value::Int(0)),
                    ("default_value", Value::Int(0)),
                    ("max_duration", ticks(c.heater_max_duration)),
                ],
            ),
            ("config_analog_in oid=%c pin=%u", vec![("oid", Value::Int(ADC_OID.into())), ("pin", pin(&c.thermistor_pin))]),
        ];
        if let Some(en) = &c.enable_pin {
            cmds.push((
                "config_digital_out oid=%c pin=%u value=%c default_value=%c max_duration=%u",
                vec![
                    ("oid", Value::Int(ENABLE_OID.into())),
                    ("pin", pin(en)),
                    ("value", Value::Int(0)),
                    ("default_value", Value::Int(1)),
                    ("max_duration", Value::Int(0)),
                ],
            ));
        }
        // Validate everything against the dictionary before sending anything: a missing pin or
        // command is reported by name with nothing half-configured.
        let mut encoded = Vec::new();
        let mut text = Vec::new();
        for (f, a) in &cmds {
            encoded.push((*f, self.mcu.dict.encode(f, a)?));
            text.push(fmt_args(f.split(' ').next().unwrap_or(""), a));
        }
        let oid_count = cmds.len() as i64;
        text.insert(0, format!("allocate_oids count={oid_count}"));
        let crc = crc32(text.join("\n").as_bytes());
        self.config_crc = crc;
        let r = self.mcu.request("get_config", &[], "config", 2.0)?;
        if r.msg.int("is_shutdown")? != 0 {
            return Err(McuError::Shutdown("the MCU is in shutdown; restart its firmware".into()));
        }
        if r.msg.int("is_config")? != 0 {
            let theirs = r.msg.int("crc")? as u32;
            if theirs != crc {
                return Err(McuError::ConfigMismatch { theirs, ours: crc });
            }
        } else {
            self.mcu.send("allocate_oids count=%c", &[("count", Value::Int(oid_count))])?;
            for (f, a) in &cmds {
                self.mcu.send(f, a)?;
            }
            self.mcu.send("finalize_config crc=%u", &[("crc", Value::Int(i64::from(crc)))])?;
            let r = self.mcu.request("get_config", &[], "config", 2.0)?;
            if r.msg.int("is_config")? == 0 || r.msg.int("crc")? as u32 != crc {
                return Err(McuError::ConfigMismatch { theirs: r.msg.int("crc")? as u32, ours: crc });
            }
        }
        // Start the temperature reports.
        let freq = self.mcu.clock_freq();
        let start = self.mcu.clock_now() + (0.2 * freq) as u64;
        let lo_adc = self.thermistor.adc_of_temp(c.max_temp) * self.adc_scale;
        let hi_adc = self.thermistor.adc_of_temp(c.min_temp) * self.adc_scale;
        self.mcu.send(
            "query_analog_in oid=%c clock=%u sample_ticks=%u sample_count=%c rest_ticks=%u bytes_per_report=%c min_value=%hu max_value=%hu range_check_count=%c",
            &[
                ("oid", Value::Int(ADC_OID.into())),
                ("clock", Value::Int(i64::from(start as u32))),
                ("sample_ticks", ticks(c.sample_time)),
                ("sample_count", Value::Int(c.sample_count.into())),
                ("rest_ticks", ticks(c.report_time)),
                ("bytes_per_report", Value::Int(2)),
                ("min_value", Value::Int(lo_adc.floor().clamp(0.0, 65535.0) as i64)),
                ("max_value", Value::Int(hi_adc.ceil().clamp(0.0, 65535.0) as i64)),
                ("range_check_count", Value::Int(4)),
            ],
        )?;
        Ok(())
    }

    /// A motor position sample from the controller: position `pos` (m of filament) at host time
    /// `t` (s, in [`Mcu::now`]'s time base; at least the lead time in the future).
    pub fn sample(&mut self, t: f64, pos: f64) {
        let steps = self.gen_.sample(t, pos);
        let Some(cs) = self.mcu.clock.as_ref() else { return };
        let clocks: Vec<(u64, u8)> =
            steps.iter().map(|&(ts, d)| (cs.clock_at(ts) as u64, if self.cfg.invert_dir { 1 - d } else { d })).collect();
        let cmds = self.sc.push(&clocks);
        self.pending_cmds.extend(cmds);
    }

    fn send_steps(&mut self, cmds: Vec<StepCmd>) -> Result<(), McuError> {
        let oid = Value::Int(STEPPER_OID.into());
        for c in cmds {
            match c {
                StepCmd::Reset { clock } => {
                    self.mcu.send(RESET_CLOCK, &[("oid", oid.clone()), ("clock", Value::Int(i64::from(clock as u32)))])?;
                }
                StepCmd::Dir(d) => self.mcu.send(SET_DIR, &[("oid", oid.clone()), ("dir", Value::Int(d.into()))])?,
                StepCmd::Queue { interval, count, add } => {
                    self.steps_sent += u64::from(count);
                    self.mcu.send(
                        QUEUE_STEP,
                        &[
                            ("oid", oid.clone()),
                            ("interval", Value::Int(interval.into())),
                            ("count", Value::Int(count.into())),
                            ("add", Value::Int(add.into())),
                        ],
                    )?;
                }
            }
        }
        Ok(())
    }

    /// Readings since the last call.
    pub fn take_readings(&mut self) -> Vec<Reading> {
        std::mem::take(&mut self.readings)
    }

    /// Services the board: sends due steps, handles temperature reports, runs the heater.
    /// Returns an error once the MCU shut down or the heater faulted (the heater is then off).
    pub fn poll(&mut self, timeout: f64) -> Result<(), McuError> {
        let freq = self.mcu.clock_freq();
        let horizon = self.mcu.clock_now() + (self.cfg.step_lead_time * freq) as u64;
        if self.sc.oldest_pending().is_some_and(|t| t < horizon) {
            let cmds = self.sc.flush();
            self.pending_cmds.extend(cmds);
        }
        let cmds = std::mem::take(&mut self.pending_cmds);
        self.send_steps(cmds)?;
        let msgs = self.mcu.poll(timeout)?;
        if let Some(s) = &self.mcu.shutdown {
            return Err(McuError::Shutdown(s.clone()));
        }
        for r in msgs {
            if r.msg.name != "analog_in_state" {
                continue;
            }
            let Ok(values) = r.msg.bytes("values") else { continue };
            let values = values.to_vec();
            let next = r.msg.int("next_clock")? as u32;
            let Some(cs) = self.mcu.clock.clone() else { continue };
            let n = values.len() / 2;
            let next64 = cs.clock32_to_64(next) as f64;
            for (i, v) in values.chunks_exact(2).enumerate() {
                let raw = f64::from(u16::from_le_bytes([v[0], v[1]]));
                let back = (n - i) as f64 * self.cfg.report_time * freq;
                let time = cs.time_of(next64 - back);
                let temp = self.thermistor.temp_of_adc(raw / self.adc_scale);
                self.on_temperature(time, temp)?;
            }
        }
        if let Some(f) = &self.fault {
            return Err(McuError::Shutdown(f.clone()));
        }
        Ok(())
    }

    fn on_temperature(&mut self, time: f64, temp: f64) -> Result<(), McuError> {
        let mut duty = 0.0;
        if self.fault.is_none() {
            if let Err(e) = self.check.check(time, temp, self.target) {
                self.fault = Some(e.to_string());
                self.target = 0.0;
            } else if self.target > 0.0 {
                duty = self.pid.update(time, temp, self.target);
            } else {
                self.pid.update(time, temp, 0.0);
            }
        }
        let reading = Reading { time, temp, duty };
        self.last = Some(reading);
        self.readings.push(reading);
        if self.refresh_heater || self.fault.is_some() {
            // Scheduled 100 ms ahead (Klipper heaters: PWM_DELAY): arrives before its clock even after
            // a retransmission or a busy host.
            let at = self.mcu.clock_now() + (0.1 * self.mcu.clock_freq()) as u64;
            let value = (duty * self.pwm_max).round() as i64;
            self.mcu.send(
                QUEUE_PWM,
                &[("oid", Value::Int(HEATER_OID.into())), ("clock", Value::Int(i64::from(at as u32))), ("value", Value::Int(value))],
            )?;
        }
        Ok(())
    }

    /// Switches the heater off: target 0 and a zero duty at once (scheduled just ahead of the MCU's
    /// clock, as every heater update), not at the next temperature report.
    pub fn heater_off(&mut self) -> Result<(), McuError> {
        self.target = 0.0;
        let at = self.mcu.clock_now() + (0.1 * self.mcu.clock_freq()) as u64;
        self.mcu.send(
            QUEUE_PWM,
            &[("oid", Value::Int(HEATER_OID.into())), ("clock", Value::Int(i64::from(at as u32))), ("value", Value::Int(0))],
        )?;
        self.mcu.poll(0.0).map(|_| ())
    }

    /// Sends every pending step now.
    pub fn flush_steps(&mut self) -> Result<(), McuError> {
        let mut cmds = std::mem::take(&mut self.pending_cmds);
        cmds.extend(self.sc.flush());
        self.send_steps(cmds)
    }
}
