//! The command-line synopsis, generated from the argument definitions so that the copy in docs/cli.md (checked by
//! `tests/readme.rs`) cannot drift from `--help`.

use clap::CommandFactory;

/// Width the synopsis lines are wrapped at.
const WIDTH: usize = 116;

/// One block per subcommand: `dpr-gpu NAME POSITIONALS [--option VALUE]...`, wrapped with continuation lines
/// indented under the first option.
pub fn synopsis() -> String {
    let cli = super::Cli::command();
    let mut out = String::new();
    for sub in cli.get_subcommands().filter(|s| s.get_name() != "help") {
        let mut words = Vec::new();
        for arg in sub.get_positionals() {
            let name = value_name(arg);
            let repeated = arg.get_num_args().is_some_and(|n| n.max_values() > 1);
            let name = if repeated { format!("{name}...") } else { name };
            words.push(if arg.is_required_set() { name } else { format!("[{name}]") });
        }
        for arg in sub.get_arguments().filter(|a| !a.is_positional() && !a.is_hide_set()) {
            let Some(long) = arg.get_long() else { continue };
            if long == "help" || long == "version" {
                continue;
            }
            let word = if arg.get_action().takes_values() {
                let repeated = arg.get_num_args().is_some_and(|n| n.max_values() > 1);
                format!("--{long} {}{}", value_name(arg), if repeated { "..." } else { "" })
            } else {
                format!("--{long}")
            };
            words.push(if arg.is_required_set() { word } else { format!("[{word}]") });
        }
        let head = format!("dpr-gpu {}", sub.get_name());
        let indent = " ".repeat(head.len() + 1);
        let mut line = head;
        for word in words {
            if line.len() + 1 + word.len() > WIDTH && !line.trim().is_empty() {
                out.push_str(&line);
                out.push('\n');
                line = indent.clone();
                line.push_str(&word);
            } else {
                line.push(' ');
                line.push_str(&word);
            }
        }
        out.push_str(&line);
        out.push('\n');
    }
    out
}

/// The argument's value name (`FILE`, `N`...), or its id in capitals.
fn value_name(arg: &clap::Arg) -> String {
    match arg.get_value_names() {
        Some([name, ..]) => name.to_string(),
        _ => arg.get_id().as_str().to_uppercase(),
    }
}
