//! The command line's flags, walked through `vibrocomp::Cli::command()`: every default
//! parses in the form help shows it, every flag has a help line, flags spelt with
//! capitals also take their lowercase spelling, and a typo is pointed at the right flag.

use crate::common::{bin, run_failing};
use clap::CommandFactory;

/// Every command (the root, each subcommand at every depth) with its path of names,
/// built (global flags propagated, as the binary parses them).
fn commands() -> Vec<(Vec<String>, clap::Command)> {
    fn walk(cmd: &clap::Command, path: Vec<String>, out: &mut Vec<(Vec<String>, clap::Command)>) {
        out.push((path.clone(), cmd.clone()));
        for sub in cmd.get_subcommands() {
            let mut p = path.clone();
            p.push(sub.get_name().to_string());
            walk(sub, p, out);
        }
    }
    let mut root = vibrocomp::Cli::command();
    root.build();
    let mut out = Vec::new();
    walk(&root, Vec::new(), &mut out);
    out
}

/// The arguments a user sets (not clap's own `--help` / `--version`).
fn user_args(cmd: &clap::Command) -> impl Iterator<Item = &clap::Arg> {
    cmd.get_arguments()
        .filter(|a| !matches!(a.get_id().as_str(), "help" | "version"))
}

/// How help shows a default (clap's own rendering: the values joined by spaces, a value
/// with whitespace quoted).
fn shown_default(arg: &clap::Arg) -> String {
    arg.get_default_values()
        .iter()
        .map(|v| {
            let v = v.to_string_lossy();
            if v.contains(char::is_whitespace) {
                format!("{v:?}")
            } else {
                v.into_owned()
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// Passing each default exactly as help displays it (split into words as a shell
/// would) gives the arguments the default gives: e.g. help once showed `--band-hz`'s
/// default as `20 2000`, which does not parse (only `20,2000` did).
#[test]
fn every_default_parses_as_help_shows_it() {
    let mut checked = 0;
    let mut wrong = Vec::new();
    for (path, cmd) in commands() {
        let help = cmd.clone().render_long_help().to_string();
        for arg in user_args(&cmd) {
            // Switches (`--json`, `-v`) have clap's implicit defaults, never shown.
            if arg.get_default_values().is_empty()
                || arg.is_hide_default_value_set()
                || !arg.get_action().takes_values()
            {
                continue;
            }
            let shown = shown_default(arg);
            let name = arg
                .get_long()
                .map_or_else(|| arg.get_id().to_string(), |l| format!("--{l}"));
            assert!(
                help.contains(&format!("[default: {shown}]")),
                "vibrocomp {} {name}: help does not show [default: {shown}]:\n{help}",
                path.join(" ")
            );
            checked += 1;
            // The expected values: what the parser makes of the default itself.
            let id = arg.get_id().as_str();
            let parse = |words: &[&str]| {
                let mut argv = vec![cmd.get_name().to_string()];
                argv.extend(words.iter().map(|w| w.to_string()));
                cmd.clone()
                    .ignore_errors(true)
                    .try_get_matches_from(argv)
                    .ok()
                    .and_then(|m| {
                        m.get_raw(id).map(|vs| {
                            vs.map(|v| v.to_string_lossy().into_owned())
                                .collect::<Vec<_>>()
                        })
                    })
            };
            let by_default = parse(&[]);
            let words: Vec<&str> = shown.split_whitespace().collect();
            let mut given = Vec::new();
            if let Some(long) = arg.get_long() {
                given.push(format!("--{long}"));
            }
            given.extend(words.iter().map(|w| w.to_string()));
            let given_refs: Vec<&str> = given.iter().map(String::as_str).collect();
            let typed = parse(&given_refs);
            // Strictly parsed, the only error allowed is another argument's absence
            // (each value passes the flag's own parser).
            let mut argv = vec![cmd.get_name().to_string()];
            argv.extend(given.iter().cloned());
            let values_ok = match cmd.clone().try_get_matches_from(argv) {
                Ok(_) => true,
                Err(e) => e.kind() == clap::error::ErrorKind::MissingRequiredArgument,
            };
            if typed != by_default || !values_ok {
                wrong.push(format!(
                    "vibrocomp {} {}: help shows [default: {shown}], which gives {typed:?}, not {by_default:?}",
                    path.join(" "),
                    given.join(" ")
                ));
            }
        }
    }
    println!("FIGURES defaults checked: {checked}");
    assert!(checked > 20, "only {checked} defaults found");
    assert!(
        wrong.is_empty(),
        "{} defaults do not parse as shown:\n{}",
        wrong.len(),
        wrong.join("\n")
    );
}

/// Every argument of every command has a help line.
#[test]
fn every_flag_has_help() {
    let mut missing = Vec::new();
    for (path, cmd) in commands() {
        for arg in user_args(&cmd) {
            let help = arg
                .get_help()
                .or(arg.get_long_help())
                .map(|h| h.to_string())
                .unwrap_or_default();
            if help.trim().is_empty() {
                missing.push(format!(
                    "vibrocomp {} {}",
                    path.join(" "),
                    arg.get_long()
                        .map_or_else(|| arg.get_id().to_string(), |l| format!("--{l}"))
                ));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "{} without help:\n{}",
        missing.len(),
        missing.join("\n")
    );
}

/// A flag spelt with capitals (`--aL3-g`, after the papers' symbols) also takes its
/// all-lowercase spelling.
#[test]
fn capitalised_flags_take_their_lowercase_spelling() {
    let mut found = Vec::new();
    let mut missing = Vec::new();
    for (path, cmd) in commands() {
        for arg in user_args(&cmd) {
            let Some(long) = arg.get_long() else { continue };
            if long == long.to_lowercase() {
                continue;
            }
            found.push(format!("{} --{long}", path.join(" ")));
            let lower = long.to_lowercase();
            let aliases = arg.get_all_aliases().unwrap_or_default();
            if !aliases.contains(&lower.as_str()) {
                missing.push(format!(
                    "vibrocomp {} --{long} (no --{lower})",
                    path.join(" ")
                ));
            }
        }
    }
    println!(
        "FIGURES capitalised flags: {}: {}",
        found.len(),
        found.join(", ")
    );
    assert!(!found.is_empty());
    assert!(missing.is_empty(), "{}", missing.join("\n"));
    // And through the binary: both spellings give the same result.
    let run = |flag: &str| {
        let out = bin()
            .args(["model", "ve", "--passport", "AL-15", flag, "2", "--json"])
            .output()
            .expect("vibrocomp runs");
        assert!(
            out.status.success(),
            "{flag}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        out.stdout
    };
    assert_eq!(run("--aL3-g"), run("--al3-g"));
}

/// A near miss of a flag gets a tip naming the right one (clap's `suggestions`).
#[test]
fn a_typo_is_pointed_at_the_right_flag() {
    let out = run_failing(&["sim", "cyclone-4-short", "--sed", "3"]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("unexpected argument '--sed'")
            && err.contains("similar argument exists: '--seed'"),
        "{err}"
    );
    let out = run_failing(&["estimate", "x.mcap", "--band-h", "20,2000"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("'--band-hz'"), "{err}");
}
