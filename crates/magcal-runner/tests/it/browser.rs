//! A real browser for the report pages: the distribution's Chromium (`/usr/bin/chromium`, or
//! `MAGCAL_CHROMIUM`) driven headless over the DevTools protocol. Each page is opened from its
//! file with the console, uncaught exceptions and every network request recorded, and WebGL
//! drawn by SwiftShader (the machines have no GPU).
//!
//! Without Chromium the tests say that they skipped; under `CI=true` they fail instead, so that
//! CI cannot pass without having looked at the pages.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use headless_chrome::protocol::cdp::Network;
use headless_chrome::protocol::cdp::Page::CaptureScreenshotFormatOption;
use headless_chrome::protocol::cdp::types::Event;
use headless_chrome::{Browser, LaunchOptions, Tab};

/// The browser of one test at a time: Chromium drawing WebGL in software takes both cores of a
/// CI machine, and two at once miss their time limits.
pub struct Chromium {
    browser: Browser,
    _turn: MutexGuard<'static, ()>,
}

impl std::ops::Deref for Chromium {
    type Target = Browser;
    fn deref(&self) -> &Browser {
        &self.browser
    }
}

static TURN: Mutex<()> = Mutex::new(());

/// The browser, or `None` (with a note) where it is not installed and CI is not set; it waits
/// while another test holds one.
pub fn chromium() -> Option<Chromium> {
    let path = std::env::var_os("MAGCAL_CHROMIUM").map_or_else(|| PathBuf::from("/usr/bin/chromium"), PathBuf::from);
    if !path.exists() {
        assert!(
            std::env::var("CI").is_err(),
            "CI is set but {} is missing: .ci/run installs Debian's chromium",
            path.display()
        );
        eprintln!("skipped: no browser at {} (apt-get install chromium)", path.display());
        return None;
    }
    // A test that failed while holding the browser poisons the lock; the next may still go.
    let turn = TURN.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let args: Vec<&OsStr> = [
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--disable-quic",
        "--disable-component-update",
        "--no-default-browser-check",
        "--allow-file-access-from-files",
    ]
    .iter()
    .map(OsStr::new)
    .collect();
    let options = LaunchOptions::default_builder()
        .path(Some(path))
        .headless(true)
        .sandbox(false)
        .enable_gpu(true)
        .window_size(Some((1280, 1000)))
        .idle_browser_timeout(Duration::from_secs(300))
        .args(args)
        .build()
        .expect("launch options");
    Some(Chromium {
        browser: Browser::new(options).expect("Chromium starts"),
        _turn: turn,
    })
}

/// A page opened in the browser, and what it did while loading.
pub struct Opened {
    pub tab: Arc<Tab>,
    /// Console errors and uncaught exceptions, as text.
    pub errors: Vec<String>,
    /// Every URL the page asked for, the page's own file included.
    pub requests: Vec<String>,
    /// From the navigation to the page's text first painted, on the page's clock, seconds.
    pub painted: f64,
    /// From the navigation to the first screen shown whole (its text painted and its figures
    /// drawn), on the page's clock, seconds.
    pub first_screen: f64,
    /// From the navigation to the first figure drawn, wherever it is on the page, on the page's
    /// clock, seconds (`None` for a page without figures).
    pub first_figure: Option<f64>,
    /// From the navigation to every figure drawn, scrolled to one after another, on the page's
    /// clock, seconds.
    pub seconds: f64,
}

impl Opened {
    /// The requests that left the page's own file (`data:` URLs are in the page).
    pub fn remote_requests(&self, page: &Path) -> Vec<String> {
        let own = format!("file://{}", page.display());
        self.requests
            .iter()
            .filter(|u| **u != own && !u.starts_with("data:"))
            .cloned()
            .collect()
    }

    /// The value of a JavaScript expression, as JSON.
    pub fn eval(&self, expression: &str) -> serde_json::Value {
        let wrapped = format!("JSON.stringify({expression})");
        let result = self.tab.evaluate(&wrapped, false).expect("evaluate");
        let text = result
            .value
            .and_then(|v| v.as_str().map(str::to_string))
            .unwrap_or_else(|| "null".into());
        serde_json::from_str(&text).expect("JSON")
    }

    /// The element `selector` as it is on the screen: scrolled into view, the viewport captured
    /// and cut to the element's rectangle (the element clip of the DevTools protocol misses
    /// WebGL canvases below the first screen).
    pub fn screenshot(&self, selector: &str) -> image::RgbaImage {
        let rect = self.eval(&format!(
            "(() => {{ const e = document.querySelector('{selector}'); e.scrollIntoView({{block: 'center'}}); const r = e.getBoundingClientRect(); return [r.left, r.top, r.width, r.height, window.devicePixelRatio]; }})()"
        ));
        let v: Vec<f64> = rect
            .as_array()
            .unwrap_or_else(|| panic!("{selector}: {rect}"))
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        // One frame after the scroll, so that the canvas is painted where it now is.
        std::thread::sleep(Duration::from_millis(200));
        let png = self
            .tab
            .capture_screenshot(CaptureScreenshotFormatOption::Png, None, None, true)
            .expect("screenshot");
        let screen = image::load_from_memory(&png).expect("a PNG").to_rgba8();
        let px = |x: f64| (x * v[4]).round().max(0.0) as u32;
        let (left, top) = (px(v[0]).min(screen.width()), px(v[1]).min(screen.height()));
        let width = px(v[2]).min(screen.width() - left);
        let height = px(v[3]).min(screen.height() - top);
        image::imageops::crop_imm(&screen, left, top, width, height).to_image()
    }
}

/// Opens the file `page` in a new tab and waits until every plotly figure on it is drawn (at most
/// `limit`).
pub fn open(browser: &Browser, page: &Path, limit: Duration) -> Opened {
    let tab = browser.new_tab().expect("a tab");
    let errors = Arc::new(Mutex::new(Vec::new()));
    let requests = Arc::new(Mutex::new(Vec::new()));
    let (e, r) = (Arc::clone(&errors), Arc::clone(&requests));
    tab.enable_log().expect("Log domain");
    tab.enable_runtime().expect("Runtime domain");
    tab.call_method(Network::Enable {
        max_total_buffer_size: None,
        max_resource_buffer_size: None,
        max_post_data_size: None,
        report_direct_socket_traffic: None,
        enable_durable_messages: None,
    })
    .expect("Network domain");
    tab.add_event_listener(Arc::new(move |event: &Event| match event {
        Event::RuntimeConsoleAPICalled(c) if format!("{:?}", c.params.Type).to_lowercase().contains("error") => {
            let args: Vec<String> = c.params.args.iter().map(|a| format!("{:?}", a.value)).collect();
            e.lock().unwrap().push(format!("console.error: {}", args.join(" ")));
        }
        Event::RuntimeExceptionThrown(x) => {
            e.lock()
                .unwrap()
                .push(format!("exception: {:?}", x.params.exception_details.text));
        }
        Event::LogEntryAdded(l) if format!("{:?}", l.params.entry.level).to_lowercase().contains("error") => {
            e.lock().unwrap().push(format!("log: {}", l.params.entry.text));
        }
        Event::NetworkRequestWillBeSent(q) => r.lock().unwrap().push(q.params.request.url.clone()),
        _ => {}
    }))
    .expect("listener");
    let started = Instant::now();
    let url = format!("file://{}", page.canonicalize().expect("the page exists").display());
    tab.navigate_to(&url)
        .expect("navigate")
        .wait_until_navigated()
        .expect("loaded");
    // The page draws a figure as it comes near the screen: first those of the first screen, then
    // each as a reader scrolls to it.
    let within = |expression: &str| {
        loop {
            let done = tab
                .evaluate(expression, false)
                .ok()
                .and_then(|r| r.value)
                .and_then(|v| v.as_bool())
                .unwrap_or(false);
            if done {
                break;
            }
            assert!(
                started.elapsed() < limit,
                "{}: the figures were not drawn within {limit:?}",
                page.display()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    within(
        "document.readyState === 'complete' && Array.from(document.querySelectorAll('.plotly-graph-div')).filter(d => d.getBoundingClientRect().top < window.innerHeight).every(d => performance.getEntriesByName('magcal-drawn ' + d.id).length > 0)",
    );
    // The page's own clock, from the navigation: the first contentful paint, and the drawing of
    // each figure of the first screen (the page marks it); the later of them is when a reader
    // sees the first screen whole. The tab's set-up over the DevTools protocol is not counted.
    let clock = tab
        .evaluate(
            "(() => { const fcp = performance.getEntriesByName('first-contentful-paint')[0]; \
             const drawn = Array.from(document.querySelectorAll('.plotly-graph-div')) \
               .filter(d => d.getBoundingClientRect().top < window.innerHeight) \
               .map(d => performance.getEntriesByName('magcal-drawn ' + d.id)[0]); \
             if (!fcp || drawn.some(m => !m)) { return null; } \
             return JSON.stringify([fcp.startTime / 1000, \
               Math.max(fcp.startTime, ...drawn.map(m => m.startTime)) / 1000]); })()",
            false,
        )
        .ok()
        .and_then(|r| r.value)
        .and_then(|v| serde_json::from_str::<serde_json::Value>(v.as_str()?).ok());
    let Some([painted, first_screen]) = clock
        .as_ref()
        .and_then(|v| v.as_array())
        .and_then(|a| Some([a.first()?.as_f64()?, a.get(1)?.as_f64()?]))
    else {
        panic!(
            "{}: no first contentful paint, or a figure of the first screen without its mark",
            page.display()
        )
    };
    let figures = tab
        .evaluate("document.querySelectorAll('.plotly-graph-div').length", false)
        .ok()
        .and_then(|r| r.value)
        .and_then(|v| v.as_u64())
        .unwrap_or(0);
    for k in 0..figures {
        let _ = tab.evaluate(
            &format!("document.querySelectorAll('.plotly-graph-div')[{k}].scrollIntoView()"),
            false,
        );
        within(&format!(
            "performance.getEntriesByName('magcal-drawn ' + document.querySelectorAll('.plotly-graph-div')[{k}].id).length > 0"
        ));
    }
    let seconds = tab
        .evaluate("performance.now() / 1000", false)
        .ok()
        .and_then(|r| r.value)
        .and_then(|v| v.as_f64())
        .expect("the page's clock");
    let first_figure = tab
        .evaluate(
            "Math.min(...performance.getEntriesByType('mark').filter(m => m.name.startsWith('magcal-drawn ')).map(m => m.startTime)) / 1000",
            false,
        )
        .ok()
        .and_then(|r| r.value)
        .and_then(|v| v.as_f64())
        .filter(|t| t.is_finite());
    let _ = tab.evaluate("window.scrollTo(0, 0)", false);
    // Let WebGL finish its first frame before anyone looks.
    std::thread::sleep(Duration::from_millis(300));
    let errors = errors.lock().unwrap().clone();
    let requests = requests.lock().unwrap().clone();
    Opened {
        tab,
        errors,
        requests,
        painted,
        first_screen,
        first_figure,
        seconds,
    }
}

/// What a screenshot shows: the share of pixels that differ from its most common colour (the
/// background) by more than 40 in some channel, and the number of distinct colours (in steps of
/// 8 per channel).
pub fn pixel_statistics(image: &image::RgbaImage) -> (f64, usize) {
    let mut counts = std::collections::HashMap::new();
    for p in image.pixels() {
        *counts.entry([p[0], p[1], p[2]]).or_insert(0usize) += 1;
    }
    let background = counts
        .iter()
        .max_by_key(|(_, n)| **n)
        .map(|(c, _)| *c)
        .unwrap_or([255; 3]);
    let differ = image
        .pixels()
        .filter(|p| (0..3).any(|i| (i32::from(p[i]) - i32::from(background[i])).abs() > 40))
        .count();
    let quantised: std::collections::HashSet<[u8; 3]> = counts.keys().map(|c| c.map(|v| v / 8)).collect();
    (
        differ as f64 / (image.width() * image.height()).max(1) as f64,
        quantised.len(),
    )
}
