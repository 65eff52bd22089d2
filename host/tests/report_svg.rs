//! SVG plot and HTML report layer.
use magcomp::report::*;

fn parse_svg(svg: &str) -> roxmltree::Document<'_> {
    roxmltree::Document::parse(svg).unwrap_or_else(|e| panic!("SVG not well-formed: {e}\n{svg}"))
}

fn demo_series(n: usize) -> (Vec<f64>, Vec<f64>) {
    let x: Vec<f64> = (0..n).map(|i| i as f64 * 0.1).collect();
    let y: Vec<f64> = x
        .iter()
        .map(|t| 52000.0 + 30.0 * (t * 0.05).sin() + 2.0 * (t * 3.1).cos())
        .collect();
    (x, y)
}

#[test]
fn every_kind_of_plot_is_well_formed_xml() {
    let (x, mut y) = demo_series(2000);
    y[100] = f64::NAN;
    let plots = vec![
        Plot::new("ts", "Total field <raw> & \"compensated\"")
            .x_label("time (s)")
            .y_label("B (nT)")
            .line("raw", &x, &y)
            .series(
                Series::line(
                    "comp",
                    &x,
                    &x.iter().map(|v| 52000.0 + v).collect::<Vec<_>>(),
                )
                .color("#000")
                .dash("5 3"),
            )
            .scatter("fixes", &x[..50], &y[..50])
            .window(20.0, 30.0, "failure <A>")
            .segment(0.0, 60.0, "cal_h045_roll")
            .segment(60.0, 200.0, "line_1010"),
        Plot::new("psd", "PSD")
            .log_log()
            .x_label("frequency (Hz)")
            .y_label("PSD (nT²/Hz)")
            .line("psd", &[0.01, 0.1, 1.0, 5.0], &[100.0, 1.0, 0.01, 0.001]),
        Plot::new("bars", "FOM per manoeuvre")
            .y_label("FOM (nT)")
            .bars(
                &["roll", "pitch", "yaw", "a very long manoeuvre label"],
                &[1.5, -0.7, f64::NAN, 3.0],
                Some(&[0.2, 0.1, 0.0, 0.5]),
            ),
        Plot::new("empty", "nothing"),
        Plot::new("flat", "constant").line("c", &[1.0, 2.0], &[5.0, 5.0]),
        Plot::new("allnan", "missing").line("m", &[1.0, 2.0], &[f64::NAN, f64::NAN]),
    ];
    for p in &plots {
        let svg = p.to_svg(800, 300);
        let doc = parse_svg(&svg);
        let root = doc.root_element();
        assert_eq!(root.tag_name().name(), "svg");
        assert_eq!(root.attribute("class"), Some("plot"));
        assert_eq!(root.attribute("data-plot"), Some(p.id()));
        assert!(
            !svg.contains("NaN") && !svg.contains("inf"),
            "{}: non-finite coordinate in SVG",
            p.id()
        );
    }
    let svg = plots[0].to_svg(800, 300);
    let doc = parse_svg(&svg);
    // Title text survives escaping intact.
    let title = doc.descendants().find(|n| n.has_tag_name("title")).unwrap();
    assert_eq!(title.text(), Some("Total field <raw> & \"compensated\""));
    // Three named series, legend entries, a window and two segment labels.
    let series = doc
        .descendants()
        .filter(|n| n.attribute("class") == Some("series"))
        .count();
    assert_eq!(series, 3);
    assert_eq!(
        doc.descendants()
            .filter(|n| n.attribute("class") == Some("legend"))
            .count(),
        3
    );
    assert_eq!(
        doc.descendants()
            .filter(|n| n.attribute("class") == Some("window"))
            .count(),
        1
    );
    assert_eq!(
        doc.descendants()
            .filter(|n| n.attribute("class") == Some("segment"))
            .count(),
        2
    );
    // The NaN breaks the raw line into two sub-paths.
    let raw = doc
        .descendants()
        .find(|n| n.attribute("data-name") == Some("raw"))
        .unwrap();
    assert_eq!(raw.attribute("d").unwrap().matches('M').count(), 2);
    let dashed = doc
        .descendants()
        .find(|n| n.attribute("data-name") == Some("comp"))
        .unwrap();
    assert_eq!(dashed.attribute("stroke-dasharray"), Some("5 3"));

    // Bars: 3 finite bars, 3 error bars (the NaN one has none), labels rotated (long one).
    let svg = plots[2].to_svg(500, 300);
    let doc = parse_svg(&svg);
    assert_eq!(
        doc.descendants()
            .filter(|n| n.attribute("class") == Some("bar"))
            .count(),
        3
    );
    assert_eq!(
        doc.descendants()
            .filter(|n| n.attribute("class") == Some("error-bar"))
            .count(),
        3
    );
    assert!(svg.contains("rotate(-40"));
    assert!(plots[3].to_svg(400, 200).contains("no data"));
}

#[test]
fn linear_ticks_are_nice_and_inside_the_range() {
    assert_eq!(
        nice_ticks(0.0, 10.0, 5),
        vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]
    );
    assert_eq!(
        nice_ticks(-0.25, 0.35, 6),
        vec![-0.2, -0.1, 0.0, 0.1, 0.2, 0.3]
    );
    assert_eq!(
        nice_ticks(52013.0, 52071.0, 6),
        vec![52020.0, 52030.0, 52040.0, 52050.0, 52060.0, 52070.0]
    );
    let t = nice_ticks(49820.0, 53420.0, 8);
    assert_eq!(
        t,
        vec![50000.0, 50500.0, 51000.0, 51500.0, 52000.0, 52500.0, 53000.0]
    );
    assert!(nice_ticks(f64::NAN, 1.0, 5).is_empty());
    assert_eq!(format_tick(0.30000000000000004, Some(0.1)), "0.3");
    assert_eq!(format_tick(-1e-17, Some(0.1)), "0");
    assert_eq!(format_tick(52020.0, Some(10.0)), "52020");
}

#[test]
fn log_ticks_are_decades_or_1_2_5() {
    assert_eq!(log_ticks(0.01, 100.0), vec![0.01, 0.1, 1.0, 10.0, 100.0]);
    assert_eq!(log_ticks(0.003, 1.5), vec![0.01, 0.1, 1.0]);
    // Fewer than three decades inside: 1-2-5.
    assert_eq!(
        log_ticks(0.003, 0.5),
        vec![0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5]
    );
    assert_eq!(log_ticks(1.5, 12.0), vec![2.0, 5.0, 10.0]);
    assert_eq!(log_ticks(0.15, 0.6), vec![0.2, 0.5]);
    // Many decades: thinned.
    let t = log_ticks(1e-12, 1e12);
    assert!(
        t.len() <= 13 && t.contains(&1.0) && t.contains(&1e12),
        "{t:?}"
    );
    assert!(log_ticks(0.0, 10.0).is_empty() && log_ticks(-1.0, 10.0).is_empty());
    let minor = log_minor_ticks(1.0, 100.0);
    assert_eq!(minor.len(), 16);
    assert!(minor.contains(&2.0) && minor.contains(&90.0) && !minor.contains(&10.0));
    assert_eq!(format_tick(0.001, None), "0.001");
    assert_eq!(format_tick(1000.0, None), "1000");
    assert_eq!(format_tick(1e-5, None), "1e-5");
    assert_eq!(format_tick(2e6, None), "2e6");
    // The log-log plot labels its axis with those decades.
    let svg = Plot::new("p", "p")
        .log_log()
        .line("s", &[0.01, 100.0], &[1e-3, 1e3])
        .to_svg(600, 400);
    let doc = parse_svg(&svg);
    let xt: Vec<&str> = doc
        .descendants()
        .filter(|n| n.attribute("class") == Some("x-ticks"))
        .flat_map(|g| g.children().filter_map(|c| c.text()))
        .collect();
    assert_eq!(xt, vec!["0.01", "0.1", "1", "10", "100"]);
}

#[test]
fn downsampling_keeps_extremes_and_gaps() {
    // One hour at 10 Hz with one spike and one dip, one sample each.
    let (x, mut y) = demo_series(36_000);
    y[12_345] = 60_000.0;
    y[30_001] = 40_000.0;
    y[20_000] = f64::NAN;
    let (dx, dy) = downsample_minmax(&x, &y, 800);
    // 2 per bucket, plus the gap: one NaN separator and the bucket it splits in two.
    assert!(dx.len() <= 2 * 800 + 3, "{} points", dx.len());
    assert!(dy.contains(&60_000.0) && dy.contains(&40_000.0));
    let fin: Vec<f64> = dy.iter().copied().filter(|v| v.is_finite()).collect();
    assert_eq!(fin.iter().cloned().fold(f64::MIN, f64::max), 60_000.0);
    assert_eq!(
        dy.iter().filter(|v| v.is_nan()).count(),
        1,
        "the gap stays a gap"
    );
    // Order preserved: x increasing across the finite points.
    let xs: Vec<f64> = dx.iter().copied().filter(|v| v.is_finite()).collect();
    assert!(xs.windows(2).all(|w| w[0] < w[1]));

    // In the SVG: small, and the spike is drawn at the top of the plot area.
    let svg = Plot::new("long", "1 h at 10 Hz")
        .line("mag", &x, &y)
        .to_svg(1000, 300);
    assert!(svg.len() < 60_000, "SVG is {} bytes", svg.len());
    let doc = parse_svg(&svg);
    let d = doc
        .descendants()
        .find(|n| n.attribute("data-name") == Some("mag"))
        .unwrap()
        .attribute("d")
        .unwrap();
    let ys: Vec<f64> = d
        .split(['M', 'L'])
        .filter_map(|p| p.split_whitespace().nth(1))
        .filter_map(|v| v.parse().ok())
        .collect();
    let (ymin, ymax) = ys
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    // Without the extremes the path would span only the thin ±32 nT band in the middle.
    assert!(ymax - ymin > 200.0, "spike and dip visible: {ymin}..{ymax}");
}

#[test]
fn html_report_escapes_and_tags_plots() {
    let (x, y) = demo_series(100);
    let report = HtmlReport::new("Flight <1003> & co")
        .paragraph("a < b")
        .section(
            Section::new("Results <final>")
                .paragraph("x & y")
                .table(
                    &["manoeuvre", "FOM (nT)"],
                    &[vec!["roll <r>".into(), "1.25".into()]],
                )
                .plot(Plot::new("ts-1", "A <plot>").line("mag", &x, &y)),
        )
        .section(Section::new("Bars").plot(Plot::new("bars", "b").bars(&["a"], &[1.0], None)));
    let html = report.to_html();
    assert!(html.starts_with("<!DOCTYPE html>"));
    assert!(html.contains("<title>Flight &lt;1003&gt; &amp; co</title>"));
    assert!(html.contains("<h1>Flight &lt;1003&gt; &amp; co</h1>"));
    assert!(html.contains("<h2>Results &lt;final&gt;</h2>"));
    assert!(html.contains("<td>roll &lt;r&gt;</td><td class=\"num\">1.25</td>"));
    assert!(!html.contains("<1003>") && !html.contains("<final>") && !html.contains("<r>"));
    assert_eq!(report.plot_ids(), vec!["ts-1", "bars"]);
    for id in report.plot_ids() {
        assert_eq!(
            html.matches(&format!("class=\"plot\" data-plot=\"{id}\""))
                .count(),
            1
        );
    }
    // The page is also well-formed XML (void elements aside), so tags balance.
    let body = &html[html.find("<main>").unwrap()..html.find("</main>").unwrap() + 7];
    roxmltree::Document::parse(body).expect("balanced HTML body");
    assert!(
        !html.contains("<script") && !html.contains("http://")
            || html.matches("http://").count()
                == html.matches("xmlns=\"http://www.w3.org/2000/svg\"").count()
    );
}

#[test]
fn odd_inputs_give_valid_svg_without_panics() {
    let nan = f64::NAN;
    let inf = f64::INFINITY;
    let plots = vec![
        Plot::new("a", "")
            .x_range(5.0, 5.0)
            .y_range(nan, 1.0)
            .line("s", &[1.0, 2.0], &[3.0, 4.0]),
        Plot::new("b", "")
            .x_range(10.0, 1.0)
            .line("", &[1.0, 2.0, 3.0], &[3.0]),
        Plot::new("c", "")
            .log_log()
            .line("neg", &[-1.0, 0.0, 2.0], &[-5.0, 0.0, -1.0]),
        Plot::new("d", "").line("huge", &[-1e308, 1e308], &[-1e308, 1e308]),
        Plot::new("e", "")
            .line("x", &[0.0, inf, 2.0], &[inf, 1.0, -inf])
            .window(nan, inf, "w"),
        Plot::new("f", "").bars(&[], &[], None),
        Plot::new("g", "").bars(&["a", "b"], &[nan, inf], Some(&[nan])),
        Plot::new("h", "")
            .segment(nan, 1.0, "s")
            .segment(3.0, 1.0, "back")
            .window(2.0, 1.0, "rev"),
        Plot::new("i", "tiny").line("t", &[0.0, 1e-300], &[1e-300, 2e-300]),
        Plot::new("j x\"y", "id with odd chars").line("s", &[1.0, 2.0], &[1.0, 2.0]),
    ];
    for p in &plots {
        for (w, h) in [(0, 0), (50, 30), (800, 300)] {
            let svg = p.to_svg(w, h);
            roxmltree::Document::parse(&svg).unwrap_or_else(|e| panic!("{}: {e}", p.id()));
            assert!(
                !svg.contains("NaN") && !svg.contains("inf"),
                "{} {w}x{h}: non-finite in {svg}",
                p.id()
            );
        }
    }
}
