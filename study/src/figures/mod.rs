//! Figures as SVG and PNG, drawn with plotters: the paper's figure set (`scmpc figures`)
//! and the plots of one run (`path` and `clearance`, written by `scmpc run`).
//!
//! Text is drawn in DejaVu Sans, embedded in the executable (the `dejavu` crate): no system
//! font is looked for. `SCMPC_FONT` names another TrueType file to use instead.

use anyhow::{Context, anyhow};
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use record::schema::Table;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

mod fleet;
mod paper;
mod run;

pub use fleet::fleet_plots;
pub use paper::{FigureSet, GAMMA_HORIZON_PAIRS, GAMMAS, HORIZONS, paper_set};
pub use run::run_plots;

/// Width and height of every figure, px.
const SIZE: (u32, u32) = (900, 700);
/// Margins of the plotting area inside a figure, px: left (with the y labels), right,
/// top (with the title), bottom (with the x labels).
const PLOT_MARGINS: (u32, u32, u32, u32) = (85, 15, 55, 60);
/// Series colours, distinguishable in print.
const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(23, 190, 207),
    RGBColor(227, 119, 194),
];

/// One curve.
#[derive(Debug, Clone, Default)]
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    /// Drawn thinner and lighter (a noisy or secondary variant).
    pub faint: bool,
    /// Drawn dashed (a route, a reference).
    pub dashed: bool,
    /// Palette index.
    pub color: usize,
    /// Drawn as dots, not joined (a lidar's returns).
    pub dots: bool,
}

/// A labelled point, drawn as a filled circle (the start, the goal).
#[derive(Debug, Clone)]
pub struct Marker {
    pub label: String,
    pub at: (f64, f64),
    /// Palette index.
    pub color: usize,
}

/// A circle to scale, drawn as its outline (a footprint, a grown boundary) or filled
/// faintly (a moving obstacle where it was), with a text beside it.
#[derive(Debug, Clone, Default)]
pub struct Ring {
    pub at: (f64, f64),
    pub radius: f64,
    /// Palette index.
    pub color: usize,
    pub dashed: bool,
    pub filled: bool,
    /// Its legend entry; empty: none (one entry stands for a whole set of rings).
    pub label: String,
    /// Written beside it, upper right (a time).
    pub text: String,
}

/// A figure: curves, obstacles to scale, horizontal reference lines.
#[derive(Debug, Clone, Default)]
pub struct Figure {
    /// File name without extension.
    pub stem: String,
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    /// Circles `(x, y, radius)` in data units, drawn filled.
    pub discs: Vec<(f64, f64, f64)>,
    /// Horizontal lines `(y, label)`: the first red, the others orange.
    pub levels: Vec<(f64, String)>,
    pub markers: Vec<Marker>,
    /// Circles drawn over the series and under the markers.
    pub rings: Vec<Ring>,
    /// Same scale on both axes (paths in the plane).
    pub equal_axes: bool,
    /// Logarithmic y axis.
    pub log_y: bool,
    /// The legend in the upper left corner (else the upper right).
    pub legend_left: bool,
    /// The legend in the corner where it covers the fewest points, markers and rings
    /// (instead of `legend_left`'s).
    pub legend_auto: bool,
}

impl Figure {
    /// Writes `<stem>.svg` and `<stem>.png` into `dir`; returns both paths.
    pub fn write(&self, dir: &Path) -> anyhow::Result<[PathBuf; 2]> {
        ensure_font()?;
        let svg = dir.join(format!("{}.svg", self.stem));
        let png = dir.join(format!("{}.png", self.stem));
        {
            let root = SVGBackend::new(&svg, SIZE).into_drawing_area();
            self.draw(&root)
                .map_err(|e| anyhow!("drawing {}: {e}", svg.display()))?;
            root.present()
                .map_err(|e| anyhow!("writing {}: {e}", svg.display()))?;
        }
        let mut pixels = vec![0u8; (SIZE.0 * SIZE.1 * 3) as usize];
        {
            let root = BitMapBackend::with_buffer(&mut pixels, SIZE).into_drawing_area();
            self.draw(&root)
                .map_err(|e| anyhow!("drawing {}: {e}", png.display()))?;
            root.present()
                .map_err(|e| anyhow!("drawing {}: {e}", png.display()))?;
        }
        write_png(&png, &pixels).with_context(|| format!("writing {}", png.display()))?;
        Ok([svg, png])
    }

    /// The ranges of the axes: the data's, padded; equal scales for paths.
    fn ranges(&self) -> ((f64, f64), (f64, f64)) {
        let mut xs: Vec<f64> = Vec::new();
        let mut ys: Vec<f64> = Vec::new();
        for s in &self.series {
            for &(x, y) in &s.points {
                if x.is_finite() && y.is_finite() {
                    xs.push(x);
                    ys.push(self.y(y));
                }
            }
        }
        for m in &self.markers {
            xs.push(m.at.0);
            ys.push(self.y(m.at.1));
        }
        let rings = self.rings.iter().map(|r| (r.at.0, r.at.1, r.radius));
        for (x, y, r) in self.discs.iter().copied().chain(rings) {
            xs.extend([x - r, x + r]);
            ys.extend([y - r, y + r]);
        }
        ys.extend(self.levels.iter().map(|l| self.y(l.0)));
        let span = |v: &[f64]| {
            let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            if lo.is_finite() && hi.is_finite() {
                let pad = ((hi - lo) * 0.05).max(1e-3);
                (lo - pad, hi + pad)
            } else {
                (0.0, 1.0)
            }
        };
        let (mut x, mut y) = (span(&xs), span(&ys));
        if self.equal_axes {
            // One metre is as long on both axes: the spans follow the plot area's shape.
            let (l, r, t, b) = PLOT_MARGINS;
            let aspect = f64::from(SIZE.0 - l - r) / f64::from(SIZE.1 - t - b);
            let half_y = ((x.1 - x.0) / aspect).max(y.1 - y.0) / 2.0;
            let (cx, cy) = ((x.0 + x.1) / 2.0, (y.0 + y.1) / 2.0);
            x = (cx - half_y * aspect, cx + half_y * aspect);
            y = (cy - half_y, cy + half_y);
        }
        if self.log_y {
            // Room above the data for the legend.
            y.1 += 0.6;
        }
        (x, y)
    }

    /// A y value as plotted (log10 on a log axis).
    fn y(&self, y: f64) -> f64 {
        if self.log_y { y.max(1e-9).log10() } else { y }
    }

    /// Draws the figure: axes, then each series and marker in turn (long: one block per
    /// kind of element, each a plotters call).
    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        root.fill(&WHITE)?;
        let ((x0, x1), (y0, y1)) = self.ranges();
        let (left, right, top, bottom) = PLOT_MARGINS;
        let mut chart = ChartBuilder::on(root)
            .caption(&self.title, ("sans-serif", 22))
            .margin_left(left - 70)
            .margin_right(right)
            .margin_top(top - 30)
            .margin_bottom(bottom - 45)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        let log_y = self.log_y;
        let y_format = move |v: &f64| y_tick_label(log_y, *v);
        chart
            .configure_mesh()
            .x_desc(self.x_label.as_str())
            .y_desc(self.y_label.as_str())
            .y_label_formatter(&y_format)
            .axis_desc_style(("sans-serif", 17))
            .label_style(("sans-serif", 14))
            .light_line_style(WHITE.mix(0.0))
            .draw()?;
        for &(cx, cy, r) in &self.discs {
            let outline: Vec<(f64, f64)> = (0..=120)
                .map(|i| {
                    let a = i as f64 / 120.0 * std::f64::consts::TAU;
                    (cx + r * a.cos(), cy + r * a.sin())
                })
                .collect();
            chart.draw_series(std::iter::once(Polygon::new(
                outline.clone(),
                RGBColor(120, 120, 120).mix(0.35).filled(),
            )))?;
            chart.draw_series(std::iter::once(PathElement::new(outline, BLACK)))?;
        }
        for (i, (y, label)) in self.levels.iter().enumerate() {
            let y = self.y(*y);
            let style = if i == 0 { RED } else { PALETTE[3] }.stroke_width(2);
            chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(x0, y), (x1, y)],
                    style,
                )))?
                .label(label.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], style));
        }
        self.draw_lines_and_markers(&mut chart)?;
        chart
            .configure_series_labels()
            .position(self.legend_position(((x0, x1), (y0, y1))))
            .label_font(("sans-serif", 15))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
        Ok(())
    }

    /// Where the legend goes: `legend_auto`, the corner of the plot whose box of the
    /// legend's likely size (40 % wide, a line per entry) holds the fewest points,
    /// markers (weighing ten) and ring centres; else `legend_left`'s.
    fn legend_position(
        &self,
        ((x0, x1), (y0, y1)): ((f64, f64), (f64, f64)),
    ) -> SeriesLabelPosition {
        use SeriesLabelPosition::*;
        if !self.legend_auto {
            return if self.legend_left {
                UpperLeft
            } else {
                UpperRight
            };
        }
        let entries = (self.series.iter().filter(|s| !s.label.is_empty()).count())
            + self.markers.len()
            + self.levels.len()
            + self.rings.iter().filter(|r| !r.label.is_empty()).count();
        let (w, h) = ((x1 - x0) * 0.4, (y1 - y0) * (0.03 + 0.035 * entries as f64));
        let points = (self
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|&p| (p, 1))))
        .chain(self.markers.iter().map(|m| (m.at, 10)))
        .chain(self.discs.iter().map(|&(x, y, _)| ((x, y), 3)))
        .chain(self.rings.iter().map(|r| (r.at, 1)));
        let covered = |left: bool, upper: bool| -> usize {
            let xs = if left { (x0, x0 + w) } else { (x1 - w, x1) };
            let ys = if upper { (y1 - h, y1) } else { (y0, y0 + h) };
            (points.clone())
                .filter(|((x, y), _)| {
                    (xs.0..=xs.1).contains(x) && (ys.0..=ys.1).contains(&self.y(*y))
                })
                .map(|(_, weight)| weight)
                .sum()
        };
        [
            (UpperLeft, true, true),
            (UpperRight, false, true),
            (LowerLeft, true, false),
            (LowerRight, false, false),
        ]
        .into_iter()
        .min_by_key(|(_, left, upper)| covered(*left, *upper))
        .map_or(UpperLeft, |(corner, _, _)| corner)
    }

    /// The rings: outlines (dashed or solid) or faint discs, each text beside its ring,
    /// and a legend entry for each ring with a label.
    fn draw_rings<DB: DrawingBackend>(
        &self,
        chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        for ring in &self.rings {
            let color = PALETTE[ring.color % PALETTE.len()];
            let style = color.stroke_width(2);
            let (cx, cy, r) = (ring.at.0, ring.at.1, ring.radius);
            let outline: Vec<(f64, f64)> = (0..=90)
                .map(|i| i as f64 / 90.0 * std::f64::consts::TAU)
                .map(|a| (cx + r * a.cos(), cy + r * a.sin()))
                .collect();
            if ring.filled {
                chart.draw_series(std::iter::once(Polygon::new(
                    outline.clone(),
                    color.mix(0.25).filled(),
                )))?;
            }
            let drawn = if ring.dashed {
                chart.draw_series(DashedLineSeries::new(outline, 6, 5, color.stroke_width(1)))?
            } else {
                chart.draw_series(LineSeries::new(outline, style))?
            };
            if !ring.label.is_empty() {
                drawn
                    .label(ring.label.as_str())
                    .legend(move |(x, y)| Circle::new((x + 12, y), 5, style));
            }
            if !ring.text.is_empty() {
                // A filled ring's (an obstacle's) upper right, an outline's lower right.
                let at = (
                    cx + r * 0.8,
                    cy + if ring.filled { r * 0.8 } else { -r * 0.8 },
                );
                chart.draw_series(std::iter::once(Text::new(
                    ring.text.clone(),
                    at,
                    ("sans-serif", 13).into_font().color(&color),
                )))?;
            }
        }
        Ok(())
    }

    /// The series (solid, faint or dashed) and the markers, each with its legend entry.
    fn draw_lines_and_markers<DB: DrawingBackend>(
        &self,
        chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        for s in &self.series {
            let color = PALETTE[s.color % PALETTE.len()];
            let style = if s.faint {
                color.mix(0.7).stroke_width(1)
            } else {
                color.stroke_width(2)
            };
            let points = s
                .points
                .iter()
                .filter(|p| p.0.is_finite() && p.1.is_finite())
                .map(|&(x, y)| (x, self.y(y)));
            let drawn = if s.dots {
                let dot = color.filled();
                let dots = points.map(|p| Circle::new(p, 2, dot));
                let drawn = chart.draw_series(dots)?;
                if !s.label.is_empty() {
                    drawn
                        .label(s.label.as_str())
                        .legend(move |(x, y)| Circle::new((x + 12, y), 3, dot));
                }
                continue;
            } else if s.dashed {
                chart.draw_series(DashedLineSeries::new(points, 8, 6, style))?
            } else {
                chart.draw_series(LineSeries::new(points, style))?
            };
            if !s.label.is_empty() {
                drawn
                    .label(s.label.as_str())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], style));
            }
        }
        self.draw_rings(chart)?;
        for m in &self.markers {
            let style = PALETTE[m.color % PALETTE.len()].filled();
            chart
                .draw_series(std::iter::once(Circle::new(
                    (m.at.0, self.y(m.at.1)),
                    6,
                    style,
                )))?
                .label(m.label.as_str())
                .legend(move |(x, y)| Circle::new((x + 12, y), 5, style));
        }
        Ok(())
    }
}

/// Names a TrueType file the figures use instead of the embedded DejaVu Sans; set but
/// empty (`SCMPC_FONT=`, the usual way to unset a variable in a script) it is unset.
pub const ENV_FONT: &str = "SCMPC_FONT";

/// Registers the figures' font for plotters' text, once per process: the file named by
/// [`ENV_FONT`], or else the embedded DejaVu Sans.
pub fn ensure_font() -> anyhow::Result<()> {
    static FONT: OnceLock<Result<(), String>> = OnceLock::new();
    FONT.get_or_init(|| {
        let named = std::env::var_os(ENV_FONT).filter(|path| !path.is_empty());
        let (name, bytes): (String, &'static [u8]) = match named {
            Some(path) => {
                let path = PathBuf::from(path);
                let bytes = std::fs::read(&path)
                    .map_err(|e| format!("{ENV_FONT}={}: {e}", path.display()))?;
                (
                    path.display().to_string(),
                    Box::leak(bytes.into_boxed_slice()),
                )
            }
            None => ("the embedded DejaVu Sans".into(), dejavu::sans::regular()),
        };
        plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
            .map_err(|_| format!("{ENV_FONT}: {name} is not a usable TrueType font"))
    })
    .clone()
    .map_err(|e| anyhow!(e))
}

fn write_png(path: &Path, rgb: &[u8]) -> anyhow::Result<()> {
    let file = std::io::BufWriter::new(std::fs::File::create(path)?);
    let mut encoder = png::Encoder::new(file, SIZE.0, SIZE.1);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header()?;
    writer.write_image_data(rgb)?;
    Ok(writer.finish()?)
}

/// One run's `trajectory.csv`, the columns the figures use.
#[derive(Debug, Clone, Default)]
pub struct Trajectory {
    pub t: Vec<f64>,
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub theta: Vec<f64>,
    pub zeta: Vec<f64>,
    pub clearance: Vec<f64>,
}

impl Trajectory {
    pub fn read(dir: &Path) -> anyhow::Result<Trajectory> {
        let table = Table::read(&dir.join("trajectory.csv"))?;
        Ok(Trajectory {
            t: table.numbers("t")?,
            x: table.numbers("x")?,
            y: table.numbers("y")?,
            theta: table.numbers("theta")?,
            zeta: table.numbers("zeta")?,
            clearance: table.numbers("clearance")?,
        })
    }

    pub fn path(&self) -> Vec<(f64, f64)> {
        self.x.iter().copied().zip(self.y.iter().copied()).collect()
    }
    fn over_time(&self, v: &[f64]) -> Vec<(f64, f64)> {
        self.t.iter().copied().zip(v.iter().copied()).collect()
    }
    /// Forward speed zeta over time, m/s.
    pub fn speed(&self) -> Vec<(f64, f64)> {
        self.over_time(&self.zeta)
    }
    pub fn clearance(&self) -> Vec<(f64, f64)> {
        self.over_time(&self.clearance)
    }
    /// Component `c` of `z = Phi(x_bar)` (goal-relative positions) over time.
    pub fn flat(&self, c: usize, goal: [f64; 2]) -> Vec<(f64, f64)> {
        (0..self.t.len())
            .map(|i| {
                let z = protocol::phi([self.x[i], self.y[i], self.theta[i], self.zeta[i]]);
                let v = match c {
                    0 => z[0] - goal[0],
                    2 => z[2] - goal[1],
                    _ => z[c],
                };
                (self.t[i], v)
            })
            .collect()
    }
}

/// The obstacles of a scenario as discs `(x, y, radius)`, where they are at t = 0.
pub fn obstacle_discs(scenario: &protocol::Scenario) -> Vec<(f64, f64, f64)> {
    scenario
        .obstacles
        .iter()
        .map(|o| (o.x, o.y, o.radius))
        .collect()
}

/// A y-axis tick label: the value to two decimals, or on a log axis (`v` = log10 of the
/// value) the value with as many decimals as it needs, up to three.
fn y_tick_label(log_y: bool, v: f64) -> String {
    if log_y {
        let value = 10f64.powf(v);
        let decimals = (1.0 - value.log10().floor()).clamp(0.0, 3.0) as usize;
        format!("{value:.decimals$}")
    } else {
        format!("{v:.2}")
    }
}
