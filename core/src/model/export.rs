//! A fitted model as one self-contained C99 header, for a controller to embed (Simulink's C
//! function block, a microcontroller, a real-time loop): the kernel expansion written out with
//! its numbers, needing only `<math.h>`.
//!
//! ```c
//! #include "model.h"
//! double state[HANDCAP_STATE_LEN], p[HANDCAP_N_INPUTS], tip[HANDCAP_N_OUTPUTS];
//! handcap_reset(state);                 /* the finger at rest: every filter at 0 input */
//! for (;;) { /* each control period dt_s */
//!     handcap_step(state, dt_s, p, tip);  /* the filters advance by dt_s, then the tip */
//! }
//! handcap_predict(p, tip);              /* the tip settled at held inputs */
//! handcap_jacobian(p, jac);             /* ∂tip/∂p there, row-major outputs × inputs */
//! ```
//!
//! Each function says what it computed from: `HANDCAP_OK` (0) inside the training range,
//! `HANDCAP_OUTSIDE` (1) where an input lies outside it (the model extrapolates: trust it less),
//! `HANDCAP_REFUSED` (−1) for an input that is not finite or a `dt_s` that is negative or not
//! finite: the outputs are NaN and the filters' state is left as it was (an infinite input would
//! otherwise give the bias as a finite tip, a NaN poison the state until a reset, and a negative
//! `dt_s` extrapolate the filters).
//!
//! The functions compute what [`Predict::predict_row`](crate::model::Predict) and
//! [`Differentiable`](crate::model::Differentiable) compute, in the same order (the numbers are
//! printed so they read back to the same `f64`), so the header agrees with `handcap predict` to
//! rounding. `handcap_step` is [`History::features`](crate::model::history::History)' filter
//! step: `handcap predict` starts each group's filters settled at its first row, which
//! `handcap_reset_at` does. The functions are `static inline`: one model per translation unit.

use std::fmt::Write;

use crate::model::file::ModelFile;
use crate::model::history::Memory;
use crate::model::StoredModel;

/// The header for `file`; `source` names the model file in its comment.
pub fn c_header(file: &ModelFile, source: &str) -> String {
    let StoredModel::Msvr(msvr) = &file.model;
    let history = file.history();
    let inputs = history.map_or(&msvr.inputs, |h| &h.inputs);
    let d = inputs.len();
    let features = msvr.inputs.len();
    let q = msvr.outputs.len();
    let centres = msvr.support_vector_count();
    let blocks = history.map_or(0, |h| h.memory.blocks());
    let memory_doc = match history.map(|h| (&h.memory, &h.time)) {
        None => "none: the outputs follow the present inputs".to_string(),
        Some((Memory::Ema { tau }, time)) => format!(
            "each input exponentially filtered with time constants {} ({time} units; dt_s in them)",
            list(tau, ", ")
        ),
        Some((Memory::Lags { rows }, _)) => format!(
            "the inputs of the {rows} previous steps (dt_s is not used: the model was fitted on rows {rows} steps apart)"
        ),
    };

    let radii = file
        .intervals
        .as_ref()
        .map_or(&[][..], |i| &i.held_out.radii[..]);

    let mut h = String::new();
    let _ = write!(
        h,
        "/* A handcap model ({source}), exported by handcap {version}: {family},
 * {centres} Gaussian kernel centres, sigma {sigma:e}.
 * Inputs, in order: {input_names}. Outputs, in order: {output_names}.
 * Input history: {memory_doc}.
 * Fitted by: {command}
 *
 * C99, only <math.h> (link with -lm). One model per translation unit.
 *   double state[HANDCAP_STATE_LEN];
 *   handcap_reset(state);                  the finger at rest: every filter at 0 input
 *   handcap_reset_at(state, inputs);       every filter settled at these inputs
 *   handcap_step(state, dt_s, inputs, out) the filters advance by dt_s, then the outputs
 *   handcap_predict(inputs, out)           the outputs settled at held inputs
 *   handcap_jacobian(inputs, jac)          d outputs / d inputs there, row-major outputs x inputs
 * step, predict and jacobian return HANDCAP_OK (0) inside the training range, HANDCAP_OUTSIDE
 * (1) where an input lies outside it (the model extrapolates), HANDCAP_REFUSED (-1) for an
 * input that is not finite or a dt_s that is negative or not finite: the outputs are then NaN
 * and the state is left as it was.
 * {intervals_doc}
 */
#ifndef HANDCAP_MODEL_H
#define HANDCAP_MODEL_H

#include <math.h>

#define HANDCAP_OK 0
#define HANDCAP_OUTSIDE 1
#define HANDCAP_REFUSED (-1)

#define HANDCAP_N_INPUTS {d}
#define HANDCAP_N_OUTPUTS {q}
/* The inputs, then each memory block's copy of them. */
#define HANDCAP_N_FEATURES {features}
#define HANDCAP_N_CENTRES {centres}
/* The filters' state (a model without history keeps none: one unused slot). */
#define HANDCAP_STATE_LEN {state_len}
#define HANDCAP_N_INTERVALS {levels}

static const char *const handcap_input_names[HANDCAP_N_INPUTS] = {{{input_strings}}};
static const char *const handcap_output_names[HANDCAP_N_OUTPUTS] = {{{output_strings}}};
",
        source = comment(&file_name(source)),
        version = comment(&file.provenance.handcap_version),
        sigma = msvr.params.sigma,
        family = file.family().description(),
        input_names = comment(&inputs.join(", ")),
        output_names = comment(&msvr.outputs.join(", ")),
        memory_doc = comment(&memory_doc),
        command = comment(&portable_command(&file.provenance.command)),
        state_len = (blocks * d).max(1),
        levels = radii.len(),
        intervals_doc = wrapped(&comment(&intervals_doc(file)), 92).join("\n * "),
        input_strings = strings(inputs),
        output_strings = strings(&msvr.outputs),
    );
    if !radii.is_empty() {
        let levels: Vec<f64> = radii.iter().map(|r| r.level).collect();
        let radius: Vec<f64> = radii.iter().map(|r| r.radius).collect();
        array(&mut h, "handcap_interval_level", &levels, levels.len());
        array(&mut h, "handcap_interval_radius", &radius, radius.len());
    }
    array(&mut h, "handcap_min_", &msvr.scaler.min, features);
    array(&mut h, "handcap_max_", &msvr.scaler.max, features);
    array(&mut h, "handcap_bias_", &msvr.bias, q);
    array(&mut h, "handcap_centres_", msvr.support_vectors(), features);
    array(&mut h, "handcap_beta_", msvr.coefficients(), q);
    let _ = writeln!(
        h,
        "static const double handcap_sigma_ = {:e};",
        msvr.params.sigma
    );
    if let Some(Memory::Ema { tau }) = history.map(|h| &h.memory) {
        let _ = writeln!(
            h,
            "static const double handcap_tau_[{blocks}] = {{{}}};",
            list(tau, ", ")
        );
    }
    h.push_str(EXPANSION);
    h.push_str(&step_functions(history.map(|h| &h.memory), blocks));
    h.push_str(STEADY_STATE);
    h.push_str("\n#endif /* HANDCAP_MODEL_H */\n");
    h
}

/// `text` in lines of at most `width` characters, broken at spaces.
fn wrapped(text: &str, width: usize) -> Vec<String> {
    let mut lines = vec![String::new()];
    for word in text.split_whitespace() {
        let line = lines.last_mut().expect("one line at least");
        if !line.is_empty() && line.len() + 1 + word.len() > width {
            lines.push(word.to_string());
        } else {
            if !line.is_empty() {
                line.push(' ');
            }
            line.push_str(word);
        }
    }
    lines
}

/// What the header's interval arrays hold, or that there are none.
fn intervals_doc(file: &ModelFile) -> String {
    match &file.intervals {
        Some(i) if !i.held_out.radii.is_empty() => {
            let widens = if i.widening.is_some() {
                " It holds where the inputs are as near the training rows as nine held-out rows \
                 in ten were; farther from them the interval is wider, by a factor this header \
                 does not compute (handcap predict --interval writes each row's radius)."
            } else {
                " The same radius for every input."
            };
            format!(
                "Prediction intervals: handcap_interval_radius[k] (output units) is the radius of the sphere around a \
                 prediction that holds the truth with probability handcap_interval_level[k] \
                 (conformal, from {} held-out rows).{widens}",
                i.held_out.rows
            )
        }
        _ => "Prediction intervals: none (the model file has none; handcap model --intervals \
              makes them)."
            .into(),
    }
}

/// The kernel expansion at the features, and its Jacobian over them: as `Msvr::predict_row`
/// and `Msvr::predict_with_jacobian`.
const EXPANSION: &str = "
/* Every output (and if jac is not 0, every derivative) NaN: what was asked has no answer. */
static inline int handcap_refuse_(double *out, double *jac)
{
    int j;
    for (j = 0; j < HANDCAP_N_OUTPUTS; j++)
        out[j] = NAN;
    if (jac)
        for (j = 0; j < HANDCAP_N_OUTPUTS * HANDCAP_N_FEATURES; j++)
            jac[j] = NAN;
    return HANDCAP_REFUSED;
}

/* HANDCAP_OK when every value is finite and inside the training range, HANDCAP_OUTSIDE when
 * one is outside it, HANDCAP_REFUSED when one is not finite. */
static inline int handcap_check_(const double *f, int n)
{
    int j, outside = 0;
    for (j = 0; j < n; j++) {
        if (!isfinite(f[j]))
            return HANDCAP_REFUSED;
        if (f[j] < handcap_min_[j] || f[j] > handcap_max_[j])
            outside = 1;
    }
    return outside ? HANDCAP_OUTSIDE : HANDCAP_OK;
}

/* The outputs at the features f, and if jac is not 0 their derivatives over f (outputs x
 * features, row-major); what handcap_check_ says of f. */
static inline int handcap_expand_(const double *f, double *out, double *jac)
{
    const double sigma2 = handcap_sigma_ * handcap_sigma_;
    const double gamma = 1.0 / (2.0 * sigma2);
    const int checked = handcap_check_(f, HANDCAP_N_FEATURES);
    double s[HANDCAP_N_FEATURES];
    int i, j, o;
    if (checked == HANDCAP_REFUSED)
        return handcap_refuse_(out, jac);
    for (j = 0; j < HANDCAP_N_FEATURES; j++)
        s[j] = (f[j] - handcap_min_[j]) / (handcap_max_[j] - handcap_min_[j]);
    for (o = 0; o < HANDCAP_N_OUTPUTS; o++)
        out[o] = handcap_bias_[o];
    if (jac)
        for (j = 0; j < HANDCAP_N_OUTPUTS * HANDCAP_N_FEATURES; j++)
            jac[j] = 0.0;
    for (i = 0; i < HANDCAP_N_CENTRES; i++) {
        const double *c = handcap_centres_ + i * HANDCAP_N_FEATURES;
        const double *beta = handcap_beta_ + i * HANDCAP_N_OUTPUTS;
        double d2 = 0.0, k;
        for (j = 0; j < HANDCAP_N_FEATURES; j++)
            d2 += (s[j] - c[j]) * (s[j] - c[j]);
        k = exp(-gamma * d2);
        for (o = 0; o < HANDCAP_N_OUTPUTS; o++) {
            out[o] += k * beta[o];
            if (jac)
                for (j = 0; j < HANDCAP_N_FEATURES; j++)
                    jac[o * HANDCAP_N_FEATURES + j] += k * beta[o] * (c[j] - s[j]);
        }
    }
    if (jac)
        for (o = 0; o < HANDCAP_N_OUTPUTS; o++)
            for (j = 0; j < HANDCAP_N_FEATURES; j++)
                jac[o * HANDCAP_N_FEATURES + j] /= sigma2 * (handcap_max_[j] - handcap_min_[j]);
    return checked;
}
";

/// The settled map: every memory block equal to the inputs; the Jacobian sums the blocks'.
const STEADY_STATE: &str = "
/* Every memory block equal to the inputs (the finger settled at them). */
static inline void handcap_settled_(const double *inputs, double *f)
{
    int j;
    for (j = 0; j < HANDCAP_N_FEATURES; j++)
        f[j] = inputs[j % HANDCAP_N_INPUTS];
}

static inline int handcap_predict(const double *inputs, double *outputs)
{
    double f[HANDCAP_N_FEATURES];
    handcap_settled_(inputs, f);
    return handcap_expand_(f, outputs, 0);
}

static inline int handcap_jacobian(const double *inputs, double *jac)
{
    double f[HANDCAP_N_FEATURES], out[HANDCAP_N_OUTPUTS];
    double full[HANDCAP_N_OUTPUTS * HANDCAP_N_FEATURES];
    int o, j, checked;
    handcap_settled_(inputs, f);
    checked = handcap_expand_(f, out, full);
    for (o = 0; o < HANDCAP_N_OUTPUTS; o++) {
        for (j = 0; j < HANDCAP_N_INPUTS; j++)
            jac[o * HANDCAP_N_INPUTS + j] = checked == HANDCAP_REFUSED ? NAN : 0.0;
        for (j = 0; j < HANDCAP_N_FEATURES; j++)
            jac[o * HANDCAP_N_INPUTS + j % HANDCAP_N_INPUTS] += full[o * HANDCAP_N_FEATURES + j];
    }
    return checked;
}
";

/// `handcap_reset`, `handcap_reset_at` and `handcap_step` for the model's memory.
fn step_functions(memory: Option<&Memory>, blocks: usize) -> String {
    let advance = match memory {
        None => "    (void)state;
    (void)dt_s;
    for (j = 0; j < HANDCAP_N_INPUTS; j++)
        f[j] = inputs[j];"
            .to_string(),
        Some(Memory::Ema { .. }) => format!(
            "    int b;
    for (j = 0; j < HANDCAP_N_INPUTS; j++)
        f[j] = inputs[j];
    for (b = 0; b < {blocks}; b++) {{
        const double gain = 1.0 - exp(-dt_s / handcap_tau_[b]);
        for (j = 0; j < HANDCAP_N_INPUTS; j++) {{
            double *x = state + b * HANDCAP_N_INPUTS + j;
            *x += gain * (inputs[j] - *x);
            f[HANDCAP_N_INPUTS + b * HANDCAP_N_INPUTS + j] = *x;
        }}
    }}"
        ),
        Some(Memory::Lags { .. }) => "    (void)dt_s;
    for (j = 0; j < HANDCAP_N_INPUTS; j++)
        f[j] = inputs[j];
    /* The state holds the previous steps' inputs, newest first. */
    for (j = HANDCAP_N_INPUTS; j < HANDCAP_N_FEATURES; j++)
        f[j] = state[j - HANDCAP_N_INPUTS];
    for (j = HANDCAP_N_FEATURES - HANDCAP_N_INPUTS - 1; j >= HANDCAP_N_INPUTS; j--)
        state[j] = state[j - HANDCAP_N_INPUTS];
    for (j = 0; j < HANDCAP_N_INPUTS; j++)
        state[j] = inputs[j];"
            .to_string(),
    };
    format!(
        "
static inline void handcap_reset_at(double *state, const double *inputs)
{{
    int j;
    for (j = 0; j < HANDCAP_STATE_LEN; j++)
        state[j] = inputs[j % HANDCAP_N_INPUTS];
}}

static inline void handcap_reset(double *state)
{{
    int j;
    for (j = 0; j < HANDCAP_STATE_LEN; j++)
        state[j] = 0.0;
}}

static inline int handcap_step(double *state, double dt_s, const double *inputs, double *outputs)
{{
    double f[HANDCAP_N_FEATURES];
    int j;
    if (!(dt_s >= 0.0) || !isfinite(dt_s)
        || handcap_check_(inputs, HANDCAP_N_INPUTS) == HANDCAP_REFUSED)
        return handcap_refuse_(outputs, 0);
{advance}
    return handcap_expand_(f, outputs, 0);
}}
"
    )
}

/// `static const double NAME[LEN] = {...};`, `per_line` numbers a line. C has no empty
/// arrays: none (a model without support vectors) is one unused 0.
fn array(h: &mut String, name: &str, values: &[f64], per_line: usize) {
    if values.is_empty() {
        let _ = writeln!(h, "static const double {name}[1] = {{0.0}}; /* none */");
        return;
    }
    let _ = writeln!(h, "static const double {name}[{}] = {{", values.len());
    for row in values.chunks(per_line.max(1)) {
        let _ = writeln!(h, "    {},", list(row, ", "));
    }
    h.push_str("};\n");
}

/// Numbers as C reads them back to the same `f64` (Rust's shortest round-trip form).
fn list(values: &[f64], separator: &str) -> String {
    values
        .iter()
        .map(|v| format!("{v:e}"))
        .collect::<Vec<_>>()
        .join(separator)
}

/// Text safe inside a C comment: neither its end nor the start of another (`-Wcomment`).
fn comment(text: &str) -> String {
    text.replace("*/", "* /")
        .replace("/*", "/ *")
        .replace(['\n', '\r'], " ")
}

/// A path's file name (the header names no folder of the machine it was made on).
fn file_name(path: &str) -> String {
    std::path::Path::new(path)
        .file_name()
        .map_or_else(|| path.to_string(), |n| n.to_string_lossy().into_owned())
}

/// The fitting command with every absolute path (alone or as `--flag=/path`) as its file name.
fn portable_command(command: &[String]) -> String {
    command
        .iter()
        .map(|arg| match arg.split_once('=') {
            Some((flag, value)) if flag.starts_with("--") && value.starts_with('/') => {
                format!("{flag}={}", file_name(value))
            }
            _ if arg.starts_with('/') => file_name(arg),
            _ => arg.clone(),
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// Names as C string literals.
fn strings(names: &[String]) -> String {
    names
        .iter()
        .map(|n| {
            let escaped: String = n
                .chars()
                .flat_map(|c| match c {
                    '"' | '\\' => vec!['\\', c],
                    c if c.is_control() || c == '?' => vec!['_'],
                    c => vec![c],
                })
                .collect();
            format!("\"{escaped}\"")
        })
        .collect::<Vec<_>>()
        .join(", ")
}
