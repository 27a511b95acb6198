//! Drawing cost: `draw()` of a full state (both sweeps' points, running fit,
//! devices, a full log) to a 120x40 TestBackend. The display redraws at most
//! 20 times a second, so this should stay far below 50 ms.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use devices::motion::AxisStatus;
use easycalib::run::events::{DeviceStatus, FitUpdate, LogLevel, Progress, RunEvent, RunPhase, SensorStatus};
use easycalib::tui::{State, draw};
use ratatui::Terminal;
use ratatui::backend::TestBackend;
use sim::generator::{GeneratorConfig, generate};

fn full_state() -> State {
    let rec = generate(&GeneratorConfig::default()).expect("default generator config is valid");
    let mut st = State::new();
    st.apply(&RunEvent::StepStarted { index: 6, total: 8, name: "torsion sweep".into(), phase: RunPhase::Torsion });
    st.apply(&RunEvent::Progress(Progress { step_fraction: 0.6, elapsed_s: 80.0, eta_s: Some(7.5) }));
    let axis = |position, moving| AxisStatus { position, moving, homed: true, enabled: true, ..AxisStatus::default() };
    st.apply(&RunEvent::DeviceStatus(DeviceStatus {
        stage: axis(1.4321, false),
        rotation: axis(2.5, true),
        sensor: SensorStatus { rate_hz: 30.0, frames: 2400, dropped: 2, ..SensorStatus::default() },
    }));
    for s in &rec.samples {
        st.apply(&RunEvent::Sample(*s));
    }
    if let Some(fit) = FitUpdate::estimate(&rec.samples, &rec.meta.indenter) {
        st.apply(&RunEvent::Fit(fit));
    }
    for i in 0..easycalib::tui::LOG_CAPACITY {
        st.apply(&RunEvent::Log { level: LogLevel::Info, message: format!("settled sample {i}") });
    }
    st
}

fn drawing(c: &mut Criterion) {
    let st = full_state();
    eprintln!("state: {} samples", st.samples());
    let mut term = Terminal::new(TestBackend::new(120, 40)).expect("test backend");
    c.bench_function("tui_draw_full_state_120x40", |b| {
        b.iter(|| {
            term.draw(|f| draw(black_box(&st), f)).expect("test backend draws");
        })
    });
}

criterion_group!(benches, drawing);
criterion_main!(benches);
