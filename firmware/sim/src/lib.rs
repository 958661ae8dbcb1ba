//! A byte-accurate model of the ST powerSTEP01 and of a daisy chain of them,
//! and of the 74HC165/74HC595 shift registers on the I/O extension's port:
//! the hardware the bridge's host tests and its QEMU image run against.
//! `no_std`, no allocation, no `unsafe`.
//!
//! * [`datasheet`] — the chip's tables as the model states them: the
//!   command table, the register table, the STATUS and CONFIG bits, and the
//!   model's own codec over them.
//! * [`chip`] — one chip: SPI parser and responses, registers, STATUS
//!   flags, the motion engine integrated exactly in chip units, SW input and
//!   fault injection.
//! * [`chain`] — N chips wired as one daisy-chain shift register, usable as
//!   the [`ChainBus`](powerstep01::ChainBus) of a driver's
//!   [`Chain`](powerstep01::Chain).
//! * [`shift`] — 74HC165/74HC595 shift registers driven at pin level (CS,
//!   SCK, MOSI per half clock period).
//! * [`vocab`] — the driver crate's names for the model's registers.
//!
//! # The model is not the driver
//!
//! A model that reads the driver's tables agrees with the driver by
//! construction, so a slip in a table is copied instead of caught. This
//! crate therefore states every table itself, from the datasheet (DS) and
//! ST's protocol note AN4290, and uses nothing of the driver crate
//! `powerstep01` but
//!
//! * the chain interface it implements ([`ChainBus`](powerstep01::ChainBus),
//!   [`MAX_DEVICES`](powerstep01::MAX_DEVICES)), and
//! * value types as a vocabulary, so that tests can compare what a chip
//!   received with what the driver meant to send: the receive log holds
//!   [`Command`](powerstep01::Command)s built by the model's own decoder,
//!   the register accessors take a [`Register`](powerstep01::Register)
//!   (mapped to an address by [`vocab`], not by the driver's table), and
//!   [`Powerstep01::status`] wraps the model's STATUS bits in the driver's
//!   [`Status`](powerstep01::Status) type.
//!
//! No encoder, decoder, classifier, register table, field layout or STATUS
//! mask of the driver is used, in the model or in its own tests. host-tests'
//! `datasheet_cross_check` compares the two sets of tables entry by entry,
//! so a slip on either side shows up as a disagreement there.
//!
//! # Strictness: what a real chip refuses or does, rule by rule
//!
//! The bridge is tested against this model, so the model must not be more
//! lenient than the datasheet: where sources differ it takes the reading
//! under which the chip refuses more. Each rule is held by the named tests
//! (in `chip/tests.rs` unless another module is named), which fail against a
//! model that skips the rule.
//!
//! | rule | source | held by |
//! |---|---|---|
//! | Every command byte by the command table (19 commands, DIR/ACT/address fields); GetStatus is 0xD0 and 0xB0 is SoftStop | DS command table (AN4290 Table 5's 1011 0000 for GetStatus is an error of the note) | `datasheet::tests::the_command_table_has_the_datasheet_encodings`, `datasheet::tests::every_accepted_frame_decodes_and_encodes_back_to_itself` |
//! | One byte per CS window; a command executes only once all its argument bytes (MSB first) are in | AN4290 §1 "Communication protocol" | `a_half_received_command_swallows_the_next_bytes` |
//! | No timeout: a half-sent command swallows the next bytes | AN4290 §1 (a started command cannot be aborted) | `a_half_received_command_swallows_the_next_bytes` |
//! | Unknown and reserved bytes (0xEB, 0xF8, …) refused with CMD_ERROR, no argument consumed | DS command management | `unknown_byte_sets_cmd_error_and_consumes_no_arguments`, `datasheet::tests::reserved_bytes_are_no_command` |
//! | SetParam of a read-only or non-existent register refused at the command byte (the next byte is a new command) | AN4290 §1 "Reading and writing registers", Figure 3 | `set_param_to_a_read_only_register_is_refused_at_the_command_byte`, `set_param_to_a_non_existent_register_is_refused_at_the_command_byte` |
//! | GetParam of a non-existent register refused | DS (treated as an unknown command) | `get_param_of_a_non_existent_register_is_an_unknown_command` |
//! | SetParam takes as many argument bytes as the register has; unused high bits are ignored | AN4290 §1 Table 4 | `register_writes_are_masked_to_the_register_width` |
//! | WS registers (ABS_POS, ACC, DEC, MIN_SPEED, ALARM_EN) refused unless stopped, after the last argument byte, value unchanged | DS register map access column, AN4290 Table 4, Figure 4 | `ws_register_written_while_moving_is_refused_after_the_last_argument` |
//! | WH registers (EL_POS, INT_SPEED, ST_SLP, FN_SLP_*, STEP_MODE, GATECFG1/2, CONFIG) refused unless in HiZ; EL_POS is WH by AN4290 Table 4 (the DS column says WS: the stricter wins) | DS register map, AN4290 Table 4 | `wh_register_written_while_not_in_hiz_is_refused`, `el_pos_is_writable_in_hiz_only` |
//! | … also right after a wake (HardStop) earlier in the same batch | (same) | `a_wh_register_write_after_a_wake_in_the_same_batch_is_refused` |
//! | GetParam/GetStatus capture the value when the command byte is decoded; a new response replaces a pending one, other commands do not disturb it | AN4290 §1, Figures 5 and 6 | `get_param_value_is_captured_when_the_command_byte_is_decoded`, `a_response_producing_command_abandons_the_pending_response`, `commands_without_response_do_not_disturb_a_pending_response` |
//! | GoTo, GoTo_DIR, GoHome, GoMark refused (CMD_ERROR) while BUSY | AN4290 §1 Table 1 notes | `goto_family_while_busy_is_refused`, `move_is_refused_while_a_run_is_still_accelerating` |
//! | Move refused unless stopped (also at constant speed) | AN4290 §1 Table 1 notes | `move_while_moving_is_refused`, `move_while_running_at_constant_speed_is_refused` |
//! | StepClock refused unless stopped | AN4290 §1 Table 1 notes | `step_clock_while_moving_is_refused` |
//! | SW input: SW_F follows the level; SW_EVN latches the closing edge (until GetStatus) | DS STATUS register, SW pin | `switch_closing_only_latches_the_event_when_sw_mode_is_1` |
//! | CONFIG.SW_MODE = 0: a closing edge hard-stops any motion | DS CONFIG register | `switch_closing_hard_stops_the_motor_when_sw_mode_is_0`, `go_until_hard_stops_when_sw_mode_is_0` |
//! | GoUntil: ACT (ABS_POS reset or copy to MARK) on the closing edge, then SoftStop with DEC | DS GoUntil command | `go_until_resets_abs_pos_on_switch_closing_then_soft_stops`, `go_until_copies_abs_pos_to_mark_with_act_1` |
//! | ReleaseSW: max(MIN_SPEED, 5 step/s) until the switch opens, then ACT and HardStop | DS ReleaseSW command | `release_sw_runs_slowly_until_the_switch_opens_then_hard_stops`, `release_sw_uses_min_speed_when_it_is_faster` |
//! | ResetDevice refused outside HiZ | ST community observation (modelling choice 1) | `reset_device_outside_hiz_is_refused` |
//! | Run speed clamped to [MIN_SPEED, MAX_SPEED] | DS Run command | `run_speed_is_clamped_to_min_and_max_speed`, `a_faster_run_accelerates_with_acc_up_to_max_speed_only` |
//! | Speed changes ramp with the chip's own ACC (up) and DEC (down), never at once | DS speed profile, ACC/DEC registers | `run_reaches_speed_after_the_analytic_acceleration_time`, `a_slower_run_decelerates_with_dec_not_at_once`, `soft_stop_decelerates_with_dec`, `run_in_the_opposite_direction_decelerates_then_reverses`, `lowering_max_speed_while_running_decelerates_to_it` |
//! | Positioning never passes its target | DS positioning commands | `go_to_and_move_land_exactly_on_random_targets`, `positioning_arrives_slowly_and_brakes_with_dec` |
//! | Every register at its reset value after power-up and reset (currents included), UVLO asserted | DS register map reset column, STATUS UVLO | `power_up_registers_hold_their_table_reset_values`, `power_cycle_restores_every_register_including_the_currents`, `power_cycle_restores_reset_registers_and_asserts_uvlo` |
//! | Latched flags (UVLO, OCD, STALL, SW_EVN, CMD_ERROR) stay until GetStatus; GetParam(STATUS) clears nothing | AN4290 §1 "Releasing the failure flags" | `get_status_clears_latched_flags_but_get_param_status_does_not`, `uvlo_reads_asserted_after_power_up_until_the_first_get_status`, `latched_thermal_status_stays_while_the_condition_persists` |
//! | Overcurrent with OC_SD and thermal shutdown switch the bridges off and refuse motion | DS CONFIG.OC_SD, thermal protection | `overcurrent_with_oc_sd_goes_hiz_and_locks_the_bridges_until_get_status`, `thermal_shutdown_puts_bridges_in_hiz_until_the_condition_clears` |
//! | ABS_POS is 22 bits two's complement and wraps | DS ABS_POS register | `abs_pos_wraps_at_22_bits` |
//! | Daisy chain: one N-byte shift register per CS window; the first byte sent lands in the far device, the first byte received came from it | AN4290 §2 | `chain::tests::window_of_n_bytes_delivers_byte_j_to_device_n_minus_1_minus_j`, `chain::tests::window_of_n_bytes_returns_device_n_minus_1_minus_j_output_in_rx_j`, `chain::tests::a_longer_window_shifts_the_first_bytes_out_onto_miso` |
//!
//! # Modelling choices (UNCONFIRMED or unspecified behaviour)
//!
//! 1. **ResetDevice outside HiZ is refused** with CMD_ERROR (a single ST
//!    community observation: STATUS read 0xE092 after a ResetDevice with the
//!    bridges on, and HardHiZ first avoided it; the datasheet is silent).
//! 2. **UVLO after reset:** power-up, ResetDevice and [`Fault::PowerCycle`]
//!    leave UVLO asserted (latched) until the first GetStatus.
//! 3. **Latching and clearing:** GetStatus returns STATUS, then clears SW_EVN
//!    and CMD_ERROR and re-evaluates UVLO, OCD, STALL and TH_STATUS from the
//!    current condition. UVLO dips, overcurrent and stall are modelled as
//!    events (their condition is gone once injected), thermal as a persisting
//!    condition ([`Fault::ThermalNormal`] ends it). TH_STATUS is treated as
//!    latched (not confirmed by the datasheet pages at hand). UVLO_ADC
//!    follows the ADCIN condition ([`Fault::AdcinLow`] /
//!    [`Fault::AdcinNormal`]) and is not latched (unconfirmed); ADC_OUT keeps
//!    its table reset value.
//! 4. **Oscillator error** ([`Powerstep01::set_clock_error_ppm`], 0 by
//!    default): the chip's time runs `1 + ppm/10⁶` as fast as the caller's,
//!    like an internal 16 MHz oscillator a few % off. The tolerance of the
//!    real one is not in the sources at hand; the motion tests use ±5 %.
//! 5. **Stall** asserts STALL_A (bit 14, ST's driver naming) only; it does
//!    not stop the motor (the chip only flags it). Which bridge bits 14 and
//!    15 belong to is disputed between sources.
//! 6. **Bridge lock:** after an overcurrent with CONFIG.OC_SD = 1, and while
//!    the thermal condition is shutdown, commands that would enable the
//!    bridges (motion and stop commands) are refused with CMD_ERROR; the
//!    overcurrent lock is released by GetStatus.
//! 7. **Floor speed:** MIN_SPEED (bits 11:0) is the start speed of every
//!    motion from rest and the speed at which decelerations end (a SoftStop
//!    stops when the speed would drop below it). LSPD_OPT (bit 12) is
//!    ignored. When MAX_SPEED < MIN_SPEED, MAX_SPEED wins.
//! 8. **ACC = 0xFFF** is infinite acceleration (speed jumps to the target,
//!    DS ACC register); DEC = 0xFFF is an ordinary finite deceleration. ACC
//!    or DEC = 0 never changes speed in that direction (no hang, the motor
//!    just keeps going).
//! 9. **Direction changes:** Run/GoUntil/GoTo… in the opposite direction while
//!    moving decelerate with DEC to the floor speed, stop, then start the
//!    other way. DIR reads the direction the motor actually turns.
//! 10. **Positioning while moving** (GoTo while a Run is at constant speed —
//!     accepted because BUSY is released): in the wrong direction the motor
//!     brakes, reverses and comes back; in the right direction with less room
//!     than the braking distance it brakes and stops abruptly on the target
//!     rather than overshoot. GoTo to the current microstep while moving stops
//!     at once on it.
//! 11. **GoUntil** waits for a SW falling edge (a switch already closed does
//!     not count), applies ACT, then SoftStops — or HardStops when
//!     CONFIG.SW_MODE is 0, because the switch hard-stop interrupt applies to
//!     every edge.
//!     **ReleaseSW** moves at max(MIN_SPEED, 5 step/s) (clamped by MAX_SPEED)
//!     until the switch opens, applies ACT, then HardStops; sent while the
//!     switch is already open it applies ACT at once and does not move.
//! 12. **Step-clock mode** is left by any motion, stop or HiZ command; each
//!     [`Powerstep01::step_clock_pulse`] moves one microstep (ignored in HiZ).
//! 13. **Dead device** ([`Fault::Dead`]): SDO stuck at the given byte, input
//!     ignored, the motion engine frozen with bridges off. [`Fault::Revive`]
//!     reconnects it with its state kept (bridges still in HiZ, parser idle,
//!     pending response dropped). A power cycle does not revive a dead device.
//! 14. **Power-up:** HiZ, stopped, DIR = forward, UVLO asserted.
//! 15. **EL_POS** follows the motion (1/128 units, 9 bits).
//! 16. **Log:** [`Powerstep01::received`] holds the last 32 fully received,
//!     decodable commands other than NOP (also those refused for a state
//!     reason); NOPs — the chain's padding — are not logged, and bytes
//!     refused at the command byte are not commands and are only counted as
//!     errors. The log survives ResetDevice and power cycles.
//! 17. **CONFIG reset value 0x2C88** (internal oscillator with 2 MHz on
//!     OSCOUT, OC_SD = 1, SW_MODE = 0): decoded from the field descriptions;
//!     the 0x2E88 quoted by some libraries is the L6470's, whose bit 9 means
//!     something else. Not read from a powerSTEP01 yet.
#![cfg_attr(not(test), no_std)]
// Tests are not bus input: they may index, unwrap and panic.
#![cfg_attr(test, allow(clippy::indexing_slicing, clippy::arithmetic_side_effects))]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

pub mod chain;
pub mod chip;
pub mod datasheet;
pub mod shift;
pub mod vocab;

pub use chain::SimChain;
pub use chip::{Fault, HomeCam, Powerstep01, TICK_NS};
pub use shift::{ConsoleCommand, ConsoleLine, Lines, ShiftChain};
