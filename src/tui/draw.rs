//! Drawing: a pure function of [`State`]. Nothing here mutates the state or
//! looks at a clock, so the same state always gives the same screen.

use ratatui::Frame;
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::style::{Color, Modifier, Style, Stylize};
use ratatui::symbols::Marker;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Axis, Block, Chart, Clear, Dataset, Gauge, GraphType, LegendPosition, Paragraph, Wrap};

use super::state::{RunStatus, State};
use crate::report::{RunDiagnosis, VerdictClass};
use crate::run::events::{FitUpdate, LogLevel, LoopView, RunControl, RunSummary, format_duration};
use devices::motion::AxisStatus;

/// Points on the drawn running-fit curve.
const CURVE_POINTS: usize = 48;
/// Width of the right-hand column (devices and fit).
const SIDE_WIDTH: u16 = 34;

/// Draw the whole screen for `state`.
pub fn draw(state: &State, frame: &mut Frame) {
    let area = frame.area();
    let [header, gauges, main, log, footer] = Layout::vertical([
        Constraint::Length(3),
        Constraint::Length(3),
        Constraint::Min(8),
        Constraint::Length(8),
        Constraint::Length(1),
    ])
    .areas(area);

    draw_header(state, frame, header);
    draw_gauges(state, frame, gauges);

    let [charts, side] = Layout::horizontal([Constraint::Min(20), Constraint::Length(SIDE_WIDTH)]).areas(main);
    let [normal, torsion] = Layout::horizontal([Constraint::Ratio(1, 2), Constraint::Ratio(1, 2)]).areas(charts);
    draw_normal_chart(state, frame, normal);
    draw_torsion_chart(state, frame, torsion);
    let [devices, rest] = Layout::vertical([Constraint::Length(11), Constraint::Min(3)]).areas(side);
    draw_devices(state, frame, devices);
    match state.closed_loop() {
        Some(v) => {
            let [fit, lp] = Layout::vertical([Constraint::Length(6), Constraint::Min(3)]).areas(rest);
            draw_fit(state, frame, fit);
            let block = Block::bordered().title(" closed loop ");
            frame.render_widget(Paragraph::new(loop_lines(v)).wrap(Wrap { trim: false }).block(block), lp);
        }
        None => draw_fit(state, frame, rest),
    }
    draw_log(state, frame, log);
    draw_footer(state, frame, footer);

    draw_banner(state, frame, charts);
    if state.help_visible() {
        draw_help(frame, area);
    }
}

fn status_style(status: &RunStatus) -> Style {
    match status {
        RunStatus::Idle => Style::new().fg(Color::Gray),
        RunStatus::Running => Style::new().fg(Color::Black).bg(Color::Green),
        RunStatus::Paused => Style::new().fg(Color::Black).bg(Color::Yellow),
        RunStatus::Aborted { .. } => Style::new().fg(Color::White).bg(Color::Red),
        RunStatus::Finished(_) => Style::new().fg(Color::Black).bg(Color::Cyan),
    }
    .add_modifier(Modifier::BOLD)
}

fn draw_header(state: &State, frame: &mut Frame, area: Rect) {
    let mut spans =
        vec![Span::styled(format!(" {} ", state.status().label()), status_style(state.status())), " ".into()];
    match state.step() {
        Some(s) => {
            spans.push(format!("step {}/{} ", s.index + 1, s.total).bold());
            spans.push(s.name.clone().into());
            spans.push(format!("  phase: {}", s.phase.as_str()).into());
        }
        None => spans.push("waiting for the sequencer".italic()),
    }
    spans.push(format!("  samples: {}", state.samples()).into());
    let block = Block::bordered().title(Line::from(" easycalib run ".bold()));
    frame.render_widget(Paragraph::new(Line::from(spans)).block(block), area);
}

fn draw_gauges(state: &State, frame: &mut Frame, area: Rect) {
    let [step_area, run_area] = Layout::horizontal([Constraint::Ratio(1, 2), Constraint::Ratio(1, 2)]).areas(area);
    let step_frac = state.step_fraction();
    let step_title = match state.step() {
        Some(s) => format!(" step: {} ", s.name),
        None => " step ".to_string(),
    };
    frame.render_widget(
        Gauge::default()
            .block(Block::bordered().title(step_title))
            .gauge_style(Style::new().fg(Color::Blue).bg(Color::Black))
            .ratio(step_frac)
            .label(format!("{:.0}%", step_frac * 100.0)),
        step_area,
    );
    let run_frac = state.overall_fraction();
    let (elapsed, eta) = match state.progress() {
        Some(p) => (format_duration(p.elapsed_s), p.eta_s.map(format_duration).unwrap_or_else(|| "--".into())),
        None => ("--".into(), "--".into()),
    };
    let eta = if matches!(state.status(), RunStatus::Finished(_)) { format_duration(0.0) } else { eta };
    frame.render_widget(
        Gauge::default()
            .block(Block::bordered().title(" run "))
            .gauge_style(Style::new().fg(Color::Green).bg(Color::Black))
            .ratio(run_frac)
            .label(format!("{:.0}%  elapsed {elapsed}  ETA {eta}", run_frac * 100.0)),
        run_area,
    );
}

/// Axis bounds covering `xs` (and 0), padded so points do not sit on the frame.
fn bounds(xs: impl Iterator<Item = f64>) -> [f64; 2] {
    let (mut lo, mut hi) = (0.0f64, 0.0f64);
    for x in xs.filter(|x| x.is_finite()) {
        lo = lo.min(x);
        hi = hi.max(x);
    }
    if hi - lo < 1e-9 {
        return [lo, lo + 1.0];
    }
    let pad = 0.05 * (hi - lo);
    [if lo < 0.0 { lo - pad } else { lo }, hi + pad]
}

fn tick(v: f64, span: f64) -> String {
    let decimals = if span >= 10.0 {
        1
    } else if span >= 1.0 {
        2
    } else {
        3
    };
    format!("{v:.decimals$}")
}

fn axis_labels(b: [f64; 2]) -> Vec<Line<'static>> {
    let span = b[1] - b[0];
    [b[0], 0.5 * (b[0] + b[1]), b[1]].iter().map(|v| Line::from(tick(*v, span))).collect()
}

/// The running-fit curve over `[x0, x1]`, only where the fit is defined.
fn curve(x: [f64; 2], f: impl Fn(f64) -> Option<f64>) -> Vec<(f64, f64)> {
    (0..=CURVE_POINTS)
        .filter_map(|i| {
            let xi = x[0] + (x[1] - x[0]) * i as f64 / CURVE_POINTS as f64;
            f(xi).filter(|y| y.is_finite()).map(|y| (xi, y))
        })
        .collect()
}

struct ChartSpec<'a> {
    title: &'a str,
    x_name: &'a str,
    y_name: &'a str,
    points: &'a [(f64, f64)],
    points_name: &'a str,
    fit: Vec<(f64, f64)>,
    fit_name: String,
    color: Color,
}

fn draw_chart(spec: ChartSpec<'_>, frame: &mut Frame, area: Rect) {
    let xb = bounds(spec.points.iter().map(|p| p.0));
    let yb = bounds(spec.points.iter().map(|p| p.1).chain(spec.fit.iter().map(|p| p.1)));
    let mut sets = vec![
        Dataset::default()
            .name(spec.points_name.to_string())
            .marker(Marker::Braille)
            .graph_type(GraphType::Scatter)
            .style(Style::new().fg(spec.color))
            .data(spec.points),
    ];
    if spec.fit.len() >= 2 {
        sets.push(
            Dataset::default()
                .name(spec.fit_name.clone())
                .marker(Marker::Braille)
                .graph_type(GraphType::Line)
                .style(Style::new().fg(Color::Magenta))
                .data(&spec.fit),
        );
    }
    let title = format!(" {} ({} pts) ", spec.title, spec.points.len());
    let chart = Chart::new(sets)
        .block(Block::bordered().title(title))
        .legend_position(Some(LegendPosition::TopLeft))
        .hidden_legend_constraints((Constraint::Ratio(1, 1), Constraint::Ratio(1, 1)))
        .x_axis(Axis::default().title(spec.x_name.to_string()).bounds(xb).labels(axis_labels(xb)).gray())
        .y_axis(Axis::default().title(spec.y_name.to_string()).bounds(yb).labels(axis_labels(yb)).gray());
    frame.render_widget(chart, area);
}

fn draw_normal_chart(state: &State, frame: &mut Frame, area: Rect) {
    let pts = state.normal_points();
    let xb = bounds(pts.iter().map(|p| p.0));
    let fit = state.fit().map(|f| curve([0.0f64.max(xb[0]), xb[1]], |x| f.gamma2_at(x))).unwrap_or_default();
    let fit_name = match state.fit().and_then(|f| f.h1) {
        Some(h1) => format!("fit H1={h1:.3}"),
        None => "fit".into(),
    };
    let spec = ChartSpec {
        title: "normal sweep: gamma2 vs gamma1",
        x_name: "gamma1 mm",
        y_name: "gamma2 mm",
        points: pts,
        points_name: "samples",
        fit,
        fit_name,
        color: Color::Cyan,
    };
    draw_chart(spec, frame, area);
}

fn draw_torsion_chart(state: &State, frame: &mut Frame, area: Rect) {
    let pts = state.torsion_points();
    let xb = bounds(pts.iter().map(|p| p.0));
    let fit = state.fit().map(|f| curve(xb, |x| f.theta2_at(x))).unwrap_or_default();
    let fit_name = match state.fit().and_then(|f| f.h3) {
        Some(h3) => format!("fit H3={h3:.3}"),
        None => "fit".into(),
    };
    let spec = ChartSpec {
        title: "torsion sweep: theta2 vs theta1",
        x_name: "theta1 deg",
        y_name: "theta2 deg",
        points: pts,
        points_name: "samples",
        fit,
        fit_name,
        color: Color::Yellow,
    };
    draw_chart(spec, frame, area);
}

fn axis_lines(name: &str, unit: &str, a: &AxisStatus) -> Vec<Line<'static>> {
    let motion = if a.moving {
        "moving".yellow()
    } else if a.homing {
        "homing".yellow()
    } else {
        "idle".green()
    };
    let homed = if a.homed { "homed".green() } else { "not homed".red() };
    let mut flags = vec!["  ".into(), motion, "  ".into(), homed];
    if a.forward_limit || a.reverse_limit {
        flags.push("  LIMIT".red().bold());
    }
    if !a.enabled {
        flags.push("  off".red());
    }
    vec![
        Line::from(vec![format!("{name:<9}").bold(), format!("{:>10.4} {unit}", a.position).into()]),
        Line::from(flags),
    ]
}

fn draw_devices(state: &State, frame: &mut Frame, area: Rect) {
    let block = Block::bordered().title(" devices ");
    let lines: Vec<Line> = match state.devices() {
        None => vec![Line::from("no device status yet".italic())],
        Some(d) => {
            let mut l = axis_lines("stage", "mm", &d.stage);
            l.extend(axis_lines("rotation", "deg", &d.rotation));
            let s = d.sensor;
            // Only frames lost on the link are a fault; frames the run did not
            // need (a full queue while it was busy) are shown plain.
            let lost = if s.dropped > 0 { format!("{}", s.dropped).red() } else { "0".green() };
            l.push(Line::from(vec![format!("{:<9}", "sensor").bold(), format!("{:>10.1} Hz", s.rate_hz).into()]));
            l.push(Line::from(vec![format!("  frames {}  lost ", s.frames).into(), lost]));
            l.push(Line::from(format!("  skipped {}  unmeasured {}", s.skipped, s.unmeasured)));
            l
        }
    };
    frame.render_widget(Paragraph::new(lines).block(block), area);
}

fn fmt_opt(v: Option<f64>, decimals: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.decimals$}"),
        _ => "--".into(),
    }
}

fn fit_lines(f: Option<&FitUpdate>) -> Vec<Line<'static>> {
    let f = f.copied().unwrap_or_default();
    vec![
        Line::from(format!("H1 {:>9}  H2 {:>9}", fmt_opt(f.h1, 4), fmt_opt(f.h2, 4))),
        Line::from(format!("H3 {:>9}", fmt_opt(f.h3, 4))),
        Line::from(vec!["E1  ".bold(), format!("{} MPa", fmt_opt(f.e1_mpa, 4)).into()]),
        Line::from(vec!["nu1 ".bold(), fmt_opt(f.nu1, 3).into()]),
    ]
}

/// The closed loop's panel: the experiment it runs and why (or why it
/// stopped), then each standing explanation with its odds, best first.
fn loop_lines(v: &LoopView) -> Vec<Line<'static>> {
    let mut l = Vec::new();
    match &v.chosen {
        Some(c) => {
            let who = if c.operator { ", operator" } else { "" };
            l.push(Line::from(format!("step {}: {} ({:.0} s{who})", v.steps_run + 1, c.name, c.rig_time_s).bold()));
            l.push(Line::from(c.why.clone()));
        }
        None => l.push(Line::from(v.note.clone())),
    }
    for h in &v.hypotheses {
        l.push(Line::from(format!("{:>3.0} % {}", 100.0 * h.odds, h.effects)));
    }
    l
}

fn draw_fit(state: &State, frame: &mut Frame, area: Rect) {
    let block = Block::bordered().title(" running fit ");
    frame.render_widget(Paragraph::new(fit_lines(state.fit())).block(block), area);
}

fn draw_log(state: &State, frame: &mut Frame, area: Rect) {
    let rows = area.height.saturating_sub(2) as usize;
    let skip = state.log().len().saturating_sub(rows);
    let lines: Vec<Line> = state
        .log()
        .skip(skip)
        .map(|e| {
            let tag = match e.level {
                LogLevel::Info => "info ".gray(),
                LogLevel::Warn => "warn ".yellow().bold(),
                LogLevel::Error => "error".red().bold(),
            };
            Line::from(vec![tag, " ".into(), e.message.clone().into()])
        })
        .collect();
    frame.render_widget(Paragraph::new(lines).block(Block::bordered().title(" log ")), area);
}

fn draw_footer(state: &State, frame: &mut Frame, area: Rect) {
    let key =
        |k: &'static str, what: &'static str| vec![Span::from(k).bold().reversed(), Span::from(format!(" {what}  "))];
    let mut spans = Vec::new();
    if state.status().is_over() {
        spans.extend(key(" q ", "leave"));
    } else if state.prompt().is_some() {
        spans.extend(key(" c ", "confirm: indenter mounted"));
        spans.extend(key(" a ", "abort"));
        spans.extend(key(" q ", "quit"));
    } else {
        spans.extend(key(" p ", "pause"));
        spans.extend(key(" r ", "resume"));
        spans.extend(key(" a ", "abort"));
        spans.extend(key(" q ", "quit"));
    }
    spans.extend(key(" ? ", "help"));
    let pending = match state.pending() {
        Some(RunControl::Pause) => Some("pausing at the next safe point…"),
        Some(RunControl::Resume) => Some("resuming…"),
        Some(RunControl::Abort) => Some("aborting: stopping motion and backing off…"),
        Some(RunControl::Quit) => Some("quitting: aborting the run first…"),
        Some(RunControl::Confirm) => Some("confirmed: the step starts…"),
        None => None,
    };
    if let Some(p) = pending {
        spans.push(p.yellow().bold());
    }
    frame.render_widget(Paragraph::new(Line::from(spans)), area);
}

/// The diagnosis' verdict and its E1, nu1 (corrected, or the calibration's when nothing is named).
fn diagnosis_lines(d: &RunDiagnosis) -> Vec<Line<'static>> {
    let verdict = d.verdict.as_str().replace('_', " ").to_uppercase();
    let style = match d.verdict {
        VerdictClass::Clean => Style::new().fg(Color::Green),
        VerdictClass::Effects => Style::new().fg(Color::Yellow),
        _ => Style::new().fg(Color::Red),
    }
    .add_modifier(Modifier::BOLD);
    // The closed loop's decision says which step it came after (the run's
    // E1 and nu1 above are then the decision's too).
    let by = d.closed_loop().and_then(|l| l.strip_prefix(crate::report::diagnosis::CLOSED_LOOP));
    let by = by.and_then(|l| l.split(':').next());
    let label = by.map_or_else(|| "diagnosis: ".to_string(), |by| format!("closed loop, after {by}: "));
    let mut head = vec![label.bold(), Span::styled(verdict, style)];
    let names: Vec<&str> = d.effects.iter().map(|e| e.name).collect();
    if !names.is_empty() {
        head.push(format!(" ({})", names.join(", ")).into());
    }
    let mut l = vec![Line::from(head)];
    if let Some(e) = &d.error {
        l.push(Line::from(format!("  {e}")));
    } else if d.corrected() {
        let (e1, nu1) = (d.ci95.e1_mpa, d.ci95.nu1);
        l.push(Line::from(format!("  corrected E1  = {:.4} MPa  95% [{:.4}, {:.4}]", d.e1_mpa, e1[0], e1[1])));
        l.push(Line::from(format!("  corrected nu1 = {:.3}  95% [{:.3}, {:.3}]", d.nu1, nu1[0], nu1[1])));
    } else {
        l.push(Line::from("  nothing named: E1 and nu1 as calibrated"));
    }
    l
}

fn summary_lines(s: &RunSummary, history: &[String], diagnosis: Option<&RunDiagnosis>) -> Vec<Line<'static>> {
    let ci = |c: Option<[f64; 2]>, d: usize| match c {
        Some([lo, hi]) => format!("  95% [{lo:.d$}, {hi:.d$}]"),
        None => String::new(),
    };
    let mut l = vec![
        Line::from(vec!["E1  = ".bold(), format!("{} MPa{}", fmt_opt(s.e1_mpa, 4), ci(s.e1_ci95, 4)).into()]),
        Line::from(vec!["nu1 = ".bold(), format!("{}{}", fmt_opt(s.nu1, 3), ci(s.nu1_ci95, 3)).into()]),
        Line::from(format!(
            "{} samples, rig time {}, wall time {}",
            s.samples,
            format_duration(s.rig_time_s),
            format_duration(s.wall_time_s)
        )),
    ];
    l.extend(diagnosis.map(diagnosis_lines).unwrap_or_default());
    if let Some(r) = &s.recording {
        l.push(Line::from(format!("recording: {r}")));
    }
    if let Some(r) = &s.report {
        l.push(Line::from(format!("report: {r}")));
    }
    for h in history {
        let alarm = h.contains("CHANGE");
        l.push(Line::from(if alarm { h.trim().to_string().bold().red() } else { h.trim().to_string().into() }));
    }
    l.push(Line::from("press q or Enter to leave".italic()));
    l
}

/// A box over the charts when the run is paused, aborted or finished.
fn draw_banner(state: &State, frame: &mut Frame, area: Rect) {
    let (title, style, lines): (&str, Style, Vec<Line>) = match state.status() {
        RunStatus::Paused => (
            " PAUSED ",
            Style::new().fg(Color::Yellow),
            vec![Line::from("The run is holding at a safe point."), Line::from("Press r to resume, a to abort.")],
        ),
        RunStatus::Aborted { reason } => (
            " RUN ABORTED ",
            Style::new().fg(Color::Red),
            vec![
                Line::from(reason.clone().bold()),
                Line::from("Motion stopped and the stage backed off."),
                Line::from("press q or Enter to leave".italic()),
            ],
        ),
        RunStatus::Finished(s) => {
            (" RUN FINISHED ", Style::new().fg(Color::Cyan), summary_lines(s, state.history(), state.diagnosis()))
        }
        RunStatus::Idle | RunStatus::Running => match state.prompt() {
            Some(p) => (
                " OPERATOR STEP ",
                Style::new().fg(Color::Magenta),
                vec![
                    Line::from(format!("{}: mount this indenter", p.step).bold()),
                    Line::from(format!("E {} MPa, nu {}, R {} mm", p.indenter.e_mpa, p.indenter.nu, p.indenter.r_mm)),
                    Line::from(p.message.clone()),
                    Line::from("Press c once it is mounted, a to abort.".italic()),
                ],
            ),
            None => return,
        },
    };
    let height = (lines.len() as u16 + 2).min(area.height);
    let width = area.width.saturating_sub(4).min(72);
    let rect = area.centered(Constraint::Length(width), Constraint::Length(height));
    frame.render_widget(Clear, rect);
    frame.render_widget(
        Paragraph::new(lines)
            .wrap(Wrap { trim: true })
            .block(Block::bordered().title(Line::from(title.bold())).border_style(style)),
        rect,
    );
}

const HELP: [(&str, &str); 7] = [
    ("c", "confirm an operator step (indenter mounted)"),
    ("p", "pause at the next safe point"),
    ("r", "resume a paused run"),
    ("a", "abort: stop motion, back the stage off"),
    ("q / Esc", "quit (aborts a run still going)"),
    ("Ctrl-C", "same as q"),
    ("?", "show / hide this help"),
];

fn draw_help(frame: &mut Frame, area: Rect) {
    let mut lines: Vec<Line> =
        HELP.iter().map(|(k, what)| Line::from(vec![format!("{k:>8}  ").bold(), (*what).into()])).collect();
    lines.push(Line::from(""));
    lines.push(Line::from("any key closes this help".italic()));
    let height = (lines.len() as u16 + 2).min(area.height);
    let width = 54.min(area.width);
    let rect = area.centered(Constraint::Length(width), Constraint::Length(height));
    frame.render_widget(Clear, rect);
    frame.render_widget(Paragraph::new(lines).block(Block::bordered().title(Line::from(" help: keys ".bold()))), rect);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::Ci95;

    fn diagnosis(summary: &str) -> RunDiagnosis {
        RunDiagnosis {
            verdict: VerdictClass::Effects,
            summary: summary.into(),
            effects: vec![crate::report::EffectFound { name: "sensor_gain", params: vec![] }],
            e1_mpa: 0.33,
            nu1: 0.39,
            ci95: Ci95 { e1_mpa: [0.3298, 0.3302], nu1: [0.386, 0.394] },
            contact_offset_mm: None,
            error: None,
            wall_time_s: 0.1,
        }
    }

    fn text(l: &Line) -> String {
        l.spans.iter().map(|s| s.content.as_ref()).collect()
    }

    /// The final panel heads the closed loop's decision with the step it came
    /// after, and a recording's own diagnosis as a diagnosis.
    #[test]
    fn the_final_panel_says_when_the_closed_loop_decided() {
        let decided = diagnosis("CLOSED LOOP, after rigid_ball: EFFECTS: sensor_gain.\n  corrected E1 ...\n");
        let l = diagnosis_lines(&decided);
        assert_eq!(text(&l[0]), "closed loop, after rigid_ball: EFFECTS (sensor_gain)");
        assert!(text(&l[1]).contains("corrected E1  = 0.3300 MPa  95% [0.3298, 0.3302]"), "{:?}", text(&l[1]));
        let own = diagnosis("EFFECTS: sensor_gain.\n");
        assert_eq!(text(&diagnosis_lines(&own)[0]), "diagnosis: EFFECTS (sensor_gain)");
    }
}
