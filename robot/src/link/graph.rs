//! What the error of a missing odometry or scan says of the ROS 2 graph: the liveliness
//! tokens the router knows of, by domain, and what to set when a publisher of the type
//! awaited is on another domain or topic (docs/ros2.md).

use ros2::MessageType;

/// What the pipeline waited for in vain: the topic (fully qualified), its DDS type and
/// the key that names the topic.
pub(super) struct Awaited<'a> {
    pub topic: &'a str,
    pub message: MessageType,
    pub key: &'static str,
}

/// The graph as the error of a missing odometry or scan gives it: what to change, when a
/// publisher of the type awaited is on another domain or topic, then the tokens by domain
/// (`domain_id`, the run's, marked).
pub(super) fn graph_text(tokens: &[String], domain_id: u32, awaited: &Awaited) -> String {
    if tokens.is_empty() {
        return "the router knows of no ROS 2 node on any domain (is this the router the \
                robot's rmw_zenoh uses?)"
            .into();
    }
    let mut text = graph_hint(tokens, domain_id, awaited).map_or(String::new(), |h| h + "; ");
    text += "the router knows of these liveliness tokens:";
    let mut domain = None;
    for token in tokens {
        // rmw_zenoh's tokens by domain; a bridge's (`@/<zid>/@ros2_lv/...`) as they come.
        let this = token
            .strip_prefix("@ros2_lv/")
            .and_then(|t| t.split('/').next());
        if this.is_some() && this != domain {
            domain = this;
            let run = if this == Some(&domain_id.to_string()) {
                " (this run's)"
            } else {
                ""
            };
            text += &format!("\n  domain {}{run}:", this.unwrap_or("?"));
        }
        text += &format!("\n    {token}");
    }
    text
}

/// What to set, when a publisher of the awaited type is on another domain, or on another
/// topic of the run's domain (rmw_zenoh's tokens: `@ros2_lv/<domain>/<session>/<node
/// id>/<entity id>/MP/<enclave>/<namespace>/<node>/<topic>/<type>/...`).
fn graph_hint(tokens: &[String], domain_id: u32, awaited: &Awaited) -> Option<String> {
    let publishers: Vec<(u32, String)> = (tokens.iter())
        .filter_map(|token| {
            let parts: Vec<&str> = token.split('/').collect();
            let (domain, kind, topic, message) =
                (parts.get(1)?, parts.get(5)?, parts.get(9)?, parts.get(10)?);
            (*kind == "MP" && *message == awaited.message.dds_name())
                .then(|| Some((domain.parse().ok()?, topic.replace('%', "/"))))?
        })
        .collect();
    let found = |on: &dyn Fn(&(u32, String)) -> bool| publishers.iter().find(|p| on(p));
    if let Some((domain, _)) = found(&|(d, t)| *d != domain_id && t == awaited.topic) {
        return Some(format!(
            "a robot publishes `{}` on domain {domain}: set `ros2.domain_id = {domain}`",
            awaited.topic
        ));
    }
    if found(&|(d, t)| *d == domain_id && t == awaited.topic).is_some() {
        return Some(format!(
            "a robot announces `{}` on `{}`, but nothing it sent arrived: its type hash \
             differs (is `ros2.distro` the robot's?)",
            awaited.message.name(),
            awaited.topic
        ));
    }
    if let Some((_, topic)) = found(&|(d, _)| *d == domain_id) {
        return Some(format!(
            "the robot publishes its `{}` on `{topic}`: set `{} = \"{topic}\"`",
            awaited.message.name(),
            awaited.key,
        ));
    }
    let (domain, topic) = found(&|_| true)?;
    Some(format!(
        "a robot publishes `{}` on `{topic}` on domain {domain}: set `ros2.domain_id = \
         {domain}` and `{}`",
        awaited.message.name(),
        awaited.key
    ))
}
