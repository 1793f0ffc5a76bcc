//! A record file that survives any end of the run: what reaches the disk ends on a whole
//! line, and it reaches it at least every [`FLUSH_PERIOD`]. The one exception is outside
//! the program: a SIGKILL that lands inside a write of several pages stops it between two
//! pages (Linux checks for a fatal signal per page), which may cut the last line.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;
use std::time::{Duration, Instant};

/// How stale the files on disk may be while a run goes on (wall time): what a kill of the
/// orchestrator (SIGKILL, a crash, the machine's OOM killer) can take from a record.
pub const FLUSH_PERIOD: Duration = Duration::from_millis(500);

/// A text file written one whole line per `writeln!`: the line is formatted apart and
/// handed to the buffer at once, so the buffer (which writes out everything it holds
/// before a line that does not fit) only ever writes whole lines.
pub struct Lines {
    file: BufWriter<File>,
    line: Vec<u8>,
}

impl Lines {
    pub fn create(path: &Path) -> std::io::Result<Lines> {
        Ok(Lines {
            file: BufWriter::new(File::create(path)?),
            line: Vec::with_capacity(256),
        })
    }

    /// What `write!`/`writeln!` call: one call must be one or more whole lines.
    pub fn write_fmt(&mut self, args: std::fmt::Arguments<'_>) -> std::io::Result<()> {
        self.line.clear();
        self.line.write_fmt(args)?;
        debug_assert!(self.line.ends_with(b"\n"), "not a whole line");
        self.file.write_all(&self.line)
    }

    pub fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

/// When the next periodic flush is due.
#[derive(Debug)]
pub struct FlushClock(Instant);

impl FlushClock {
    pub fn new() -> FlushClock {
        FlushClock(Instant::now())
    }

    /// Whether [`FLUSH_PERIOD`] has passed since the last time this said so.
    pub fn due(&mut self) -> bool {
        let now = Instant::now();
        if now.duration_since(self.0) >= FLUSH_PERIOD {
            self.0 = now;
            true
        } else {
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_file_on_disk_ends_on_a_whole_line_whatever_the_buffer_held() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.csv");
        let mut lines = Lines::create(&path).unwrap();
        // Lines of many lengths, so the buffer fills part-way through one of them many
        // times over; the file is read without a flush, as a kill would leave it.
        let mut written_out = 0;
        for i in 0..5000 {
            writeln!(lines, "{i},{}", "x".repeat(i % 97)).unwrap();
            if std::fs::metadata(&path).unwrap().len() != written_out {
                let on_disk = std::fs::read(&path).unwrap();
                assert!(on_disk.ends_with(b"\n"), "cut after line {i}");
                written_out = on_disk.len() as u64;
            }
        }
        assert!(written_out > 0, "the buffer never wrote out");
        lines.flush().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(text.lines().count(), 5000);
    }
}
