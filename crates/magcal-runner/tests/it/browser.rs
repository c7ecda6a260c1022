//! A real browser for the report pages: the distribution's Chromium (`/usr/bin/chromium`, or
//! `MAGCAL_CHROMIUM`) driven headless over the DevTools protocol. Each page is opened from its
//! file with the console, uncaught exceptions and every network request recorded, and WebGL
//! drawn by SwiftShader (the machines have no GPU).
//!
//! The protocol goes over the pipe Chromium opens with `--remote-debugging-pipe` (commands on its
//! file descriptor 3, replies and events on 4, each a JSON text ended by a NUL byte): a dozen
//! commands, two threads and no client crate. The `headless_chrome` crate did the same over a
//! WebSocket, but it and the crates only it brought in (its generated protocol types, a TLS stack
//! for a download switched off, a WebSocket client) were 121 s of the 467 s of CPU of a clean
//! `cargo clippy` and 171 s of the 1,126 s of a clean `cargo test --release` build, for code that
//! waits on the browser.
//!
//! Without Chromium the tests say that they skipped; under `CI=true` they fail instead, so that
//! CI cannot pass without having looked at the pages.

use std::collections::HashMap;
use std::io::{BufRead, BufReader, Write};
use std::os::fd::AsRawFd;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use base64::Engine;
use serde_json::{Value, json};

/// Chromium's switches: those a test browser is started with (as the crates that drive Chromium
/// do: no background work, no first-run pages, no throttling of a tab that is not in front) and
/// WebGL by SwiftShader.
const SWITCHES: [&str; 27] = [
    "--headless",
    "--remote-debugging-pipe",
    "--no-sandbox",
    "--window-size=1280,1000",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-quic",
    "--disable-component-update",
    "--no-default-browser-check",
    "--allow-file-access-from-files",
    "--disable-background-networking",
    "--disable-background-timer-throttling",
    "--disable-backgrounding-occluded-windows",
    "--disable-breakpad",
    "--disable-client-side-phishing-detection",
    "--disable-default-apps",
    "--disable-dev-shm-usage",
    "--disable-extensions",
    "--disable-features=TranslateUI",
    "--disable-hang-monitor",
    "--disable-ipc-flooding-protection",
    "--disable-popup-blocking",
    "--disable-renderer-backgrounding",
    "--disable-sync",
    "--force-color-profile=srgb",
    "--metrics-recording-only",
    "--no-first-run",
];

/// How long a command may wait for its reply.
const REPLY_LIMIT: Duration = Duration::from_secs(120);

/// What came back from the browser: replies by command id, and events by the session (tab) they
/// belong to, in their order.
#[derive(Default)]
struct Inbox {
    replies: HashMap<u64, Result<Value, String>>,
    events: HashMap<String, Vec<Value>>,
    /// Set when the browser's end of the pipe closed.
    closed: bool,
}

/// One connection to a running Chromium.
struct Connection {
    to_browser: Mutex<(std::io::PipeWriter, u64)>,
    inbox: Mutex<Inbox>,
    arrived: Condvar,
}

impl Connection {
    /// Sends `method` (to the tab `session`, or the browser) and waits for its result.
    fn call(&self, session: Option<&str>, method: &str, params: Value) -> Result<Value, String> {
        let id = {
            let mut out = self.to_browser.lock().unwrap();
            out.1 += 1;
            let id = out.1;
            let mut message = json!({ "id": id, "method": method, "params": params });
            if let Some(s) = session {
                message["sessionId"] = Value::from(s);
            }
            let mut bytes = serde_json::to_vec(&message).unwrap();
            bytes.push(0);
            out.0.write_all(&bytes).map_err(|e| format!("{method}: {e}"))?;
            id
        };
        self.wait(method, REPLY_LIMIT, |inbox| inbox.replies.remove(&id))?
            .map_err(|e| format!("{method}: {e}"))
    }

    /// Waits until `found` finds something in the inbox (at most `limit`); `what` names it in
    /// the error of a browser that closed its pipe or did not answer in time.
    fn wait<T>(
        &self,
        what: &str,
        limit: Duration,
        mut found: impl FnMut(&mut Inbox) -> Option<T>,
    ) -> Result<T, String> {
        let started = Instant::now();
        let mut inbox = self.inbox.lock().unwrap();
        loop {
            if let Some(t) = found(&mut inbox) {
                return Ok(t);
            }
            if inbox.closed {
                return Err(format!("{what}: the browser closed its pipe"));
            }
            let left = limit
                .checked_sub(started.elapsed())
                .ok_or_else(|| format!("{what}: nothing within {limit:?}"))?;
            inbox = self.arrived.wait_timeout(inbox, left).unwrap().0;
        }
    }

    /// Reads the browser's messages until its end of the pipe closes.
    fn listen(&self, from_browser: std::io::PipeReader) {
        let mut reader = BufReader::new(from_browser);
        let mut bytes = Vec::new();
        loop {
            bytes.clear();
            match reader.read_until(0, &mut bytes) {
                Ok(n) if n > 0 && bytes.last() == Some(&0) => {}
                _ => break,
            }
            bytes.pop();
            let Ok(message) = serde_json::from_slice::<Value>(&bytes) else {
                continue;
            };
            let mut inbox = self.inbox.lock().unwrap();
            if let Some(id) = message["id"].as_u64() {
                let reply = match message.get("error") {
                    Some(e) => Err(e.to_string()),
                    None => Ok(message["result"].clone()),
                };
                inbox.replies.insert(id, reply);
            } else if let Some(session) = message["sessionId"].as_str() {
                inbox.events.entry(session.to_string()).or_default().push(message);
            }
            drop(inbox);
            self.arrived.notify_all();
        }
        self.inbox.lock().unwrap().closed = true;
        self.arrived.notify_all();
    }
}

/// A running headless Chromium, ended (and its profile removed) when dropped.
pub struct Browser {
    connection: Arc<Connection>,
    child: Child,
    _profile: tempfile::TempDir,
}

impl Browser {
    /// Starts the Chromium at `path` with a fresh profile.
    fn launch(path: &Path) -> Self {
        let profile = tempfile::TempDir::new().expect("a profile directory");
        let (commands, to_browser) = std::io::pipe().expect("a pipe");
        let (from_browser, replies) = std::io::pipe().expect("a pipe");
        let (read_fd, write_fd) = (commands.as_raw_fd(), replies.as_raw_fd());
        let mut command = Command::new(path);
        command
            .args(SWITCHES)
            .arg(format!("--user-data-dir={}", profile.path().display()))
            .arg("about:blank")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        // SAFETY: between fork and exec only `dup`/`dup2`, which are async-signal-safe. Both ends
        // are first moved to descriptors above 4, so that neither is overwritten by the other's
        // `dup2` (the duplicates made by `dup2` are not closed on exec, the originals are).
        unsafe {
            command.pre_exec(move || {
                let high = |fd| match libc::fcntl(fd, libc::F_DUPFD_CLOEXEC, 10) {
                    -1 => Err(std::io::Error::last_os_error()),
                    fd => Ok(fd),
                };
                let (r, w) = (high(read_fd)?, high(write_fd)?);
                if libc::dup2(r, 3) == -1 || libc::dup2(w, 4) == -1 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
        let child = command.spawn().expect("Chromium starts");
        // The browser's ends, in this process, close: the pipe ends when Chromium's close.
        drop((commands, replies));
        let connection = Arc::new(Connection {
            to_browser: Mutex::new((to_browser, 0)),
            inbox: Mutex::new(Inbox::default()),
            arrived: Condvar::new(),
        });
        let listener = Arc::clone(&connection);
        std::thread::spawn(move || listener.listen(from_browser));
        Browser {
            connection,
            child,
            _profile: profile,
        }
    }

    /// A new tab, attached (its events recorded from now on).
    pub fn new_tab(&self) -> Result<Tab, String> {
        let target = self
            .connection
            .call(None, "Target.createTarget", json!({ "url": "about:blank" }))?;
        let target = target["targetId"].as_str().ok_or("no targetId")?.to_string();
        let session = self.connection.call(
            None,
            "Target.attachToTarget",
            json!({ "targetId": target, "flatten": true }),
        )?;
        let session = session["sessionId"].as_str().ok_or("no sessionId")?.to_string();
        Ok(Tab {
            connection: Arc::clone(&self.connection),
            target,
            session,
        })
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.connection.call(None, "Browser.close", json!({}));
        let started = Instant::now();
        while started.elapsed() < Duration::from_secs(5) {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// One tab of the browser.
pub struct Tab {
    connection: Arc<Connection>,
    target: String,
    session: String,
}

impl Tab {
    /// Calls `method` in this tab.
    pub fn call(&self, method: &str, params: Value) -> Result<Value, String> {
        self.connection.call(Some(&self.session), method, params)
    }

    /// The value of a JavaScript expression (JSON-able values; an exception is an error).
    pub fn evaluate(&self, expression: &str) -> Result<Value, String> {
        let result = self.call(
            "Runtime.evaluate",
            json!({ "expression": expression, "returnByValue": true }),
        )?;
        if let Some(e) = result.get("exceptionDetails") {
            return Err(e.to_string());
        }
        Ok(result["result"].get("value").cloned().unwrap_or(Value::Null))
    }

    /// The events of this tab so far, in their order.
    pub fn events(&self) -> Vec<Value> {
        let inbox = self.connection.inbox.lock().unwrap();
        inbox.events.get(&self.session).cloned().unwrap_or_default()
    }

    /// Waits until the event `method` has arrived in this tab (at most `limit`).
    pub fn wait_for(&self, method: &str, limit: Duration) -> Result<(), String> {
        self.connection.wait(method, limit, |inbox| {
            inbox
                .events
                .get(&self.session)
                .is_some_and(|e| e.iter().any(|m| m["method"] == method))
                .then_some(())
        })
    }

    /// The viewport as a PNG.
    pub fn capture_screenshot(&self) -> Result<Vec<u8>, String> {
        let shot = self.call(
            "Page.captureScreenshot",
            json!({ "format": "png", "fromSurface": true }),
        )?;
        let data = shot["data"].as_str().ok_or("no data")?;
        base64::engine::general_purpose::STANDARD
            .decode(data)
            .map_err(|e| e.to_string())
    }

    /// Closes the tab.
    pub fn close(&self) -> Result<(), String> {
        self.connection
            .call(None, "Target.closeTarget", json!({ "targetId": self.target }))
            .map(drop)
    }
}

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
    Some(Chromium {
        browser: Browser::launch(&path),
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
    pub fn eval(&self, expression: &str) -> Value {
        self.tab
            .evaluate(expression)
            .unwrap_or_else(|e| panic!("{expression}: {e}"))
    }

    /// The element `selector` as it is on the screen: scrolled into view, the viewport captured
    /// and cut to the element's rectangle (a clip of the capture misses WebGL canvases below the
    /// first screen).
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
        let png = self.tab.capture_screenshot().expect("screenshot");
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
    for domain in ["Log", "Runtime", "Network", "Page"] {
        tab.call(&format!("{domain}.enable"), json!({}))
            .unwrap_or_else(|e| panic!("{domain} domain: {e}"));
    }
    // A tab behind another is not painted, and has no paint timings.
    tab.call("Page.bringToFront", json!({})).expect("the tab in front");
    let started = Instant::now();
    let url = format!("file://{}", page.canonicalize().expect("the page exists").display());
    let navigated = tab.call("Page.navigate", json!({ "url": url })).expect("navigate");
    assert!(navigated.get("errorText").is_none(), "{url}: {navigated}");
    tab.wait_for("Page.loadEventFired", limit).expect("loaded");
    // The page draws a figure as it comes near the screen: first those of the first screen, then
    // each as a reader scrolls to it.
    let within = |expression: &str| {
        loop {
            if tab.evaluate(expression).ok().and_then(|v| v.as_bool()) == Some(true) {
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
        "document.readyState === 'complete' && performance.getEntriesByName('first-contentful-paint').length > 0 && Array.from(document.querySelectorAll('.plotly-graph-div')).filter(d => d.getBoundingClientRect().top < window.innerHeight).every(d => performance.getEntriesByName('magcal-drawn ' + d.id).length > 0)",
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
             return [fcp.startTime / 1000, \
               Math.max(fcp.startTime, ...drawn.map(m => m.startTime)) / 1000]; })()",
        )
        .ok();
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
        .evaluate("document.querySelectorAll('.plotly-graph-div').length")
        .ok()
        .and_then(|v| v.as_u64())
        .unwrap_or(0);
    for k in 0..figures {
        let _ = tab.evaluate(&format!(
            "document.querySelectorAll('.plotly-graph-div')[{k}].scrollIntoView()"
        ));
        within(&format!(
            "performance.getEntriesByName('magcal-drawn ' + document.querySelectorAll('.plotly-graph-div')[{k}].id).length > 0"
        ));
    }
    let seconds = tab
        .evaluate("performance.now() / 1000")
        .ok()
        .and_then(|v| v.as_f64())
        .expect("the page's clock");
    // `Math.min` of no marks is Infinity, which JSON carries as null.
    let first_figure = tab
        .evaluate(
            "Math.min(...performance.getEntriesByType('mark').filter(m => m.name.startsWith('magcal-drawn ')).map(m => m.startTime)) / 1000",
        )
        .ok()
        .and_then(|v| v.as_f64())
        .filter(|t| t.is_finite());
    let _ = tab.evaluate("window.scrollTo(0, 0)");
    // Let WebGL finish its first frame before anyone looks.
    std::thread::sleep(Duration::from_millis(300));
    let mut errors = Vec::new();
    let mut requests = Vec::new();
    for event in tab.events() {
        let params = &event["params"];
        match event["method"].as_str() {
            Some("Runtime.consoleAPICalled") if params["type"] == "error" => {
                let args: Vec<String> = params["args"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .map(|a| a.get("value").unwrap_or(&a["description"]).to_string())
                    .collect();
                errors.push(format!("console.error: {}", args.join(" ")));
            }
            Some("Runtime.exceptionThrown") => {
                let details = &params["exceptionDetails"];
                errors.push(format!(
                    "exception: {} {}",
                    details["text"], details["exception"]["description"]
                ));
            }
            Some("Log.entryAdded") if params["entry"]["level"] == "error" => {
                errors.push(format!("log: {}", params["entry"]["text"]));
            }
            Some("Network.requestWillBeSent") => {
                requests.push(params["request"]["url"].as_str().unwrap_or_default().to_string());
            }
            _ => {}
        }
    }
    Opened {
        tab: Arc::new(tab),
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
