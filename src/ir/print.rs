//! Pretty printer: the simplified formula as `lobe check` shows it.

use super::*;

/// Binding strength in the .brdf grammar, loosest first: `?:` 1, `||` 2, `&&` 3, comparisons 4, `+ -` 5,
/// `* /` 6, unary 7, atoms and calls 8. Comparisons and selects print in operator form (see [`write`]).
fn prec(n: &Node) -> u8 {
    use crate::builtins::Builtin as B;
    match n {
        Node::Call(B::Select, _) => 1,
        Node::Call(B::Lt | B::Le | B::Eq | B::Ne, _) => 4,
        Node::Binary(BinOp::Add | BinOp::Sub, ..) => 5,
        Node::Binary(BinOp::Mul | BinOp::Div, ..) => 6,
        Node::Neg(_) => 7,
        Node::Const(b) if f64::from_bits(*b) < 0.0 => 7,
        _ => 8,
    }
}

/// A constant as the language reads it back: `number`, except that the non-finite values, which have no
/// literal, print as the divisions that make them.
fn literal(v: f64) -> String {
    match v {
        _ if v.is_nan() => "(0/0)".into(),
        f64::INFINITY => "(1/0)".into(),
        f64::NEG_INFINITY => "(-1/0)".into(),
        _ => number(v),
    }
}

/// A number for people: `pi`, `inf`, `nan`, or the shortest decimal that reads back exactly.
pub(crate) fn number(v: f64) -> String {
    if v.is_nan() {
        return "nan".into();
    }
    if v.is_infinite() {
        return if v > 0.0 { "inf".into() } else { "-inf".into() };
    }
    if v == std::f64::consts::PI {
        return "pi".into();
    }
    let s = format!("{v}");
    if s.len() > 18 {
        format!("{v:e}")
    } else {
        s
    }
}

pub(crate) fn expr(f: &Formula, id: NodeId) -> String {
    let mut out = String::new();
    write(f, id, &mut out, &HashMap::new());
    out
}

/// The formula with every shared non-leaf subexpression named once, as the .brdf language writes it:
/// `let nh = clamp(NH, 0, 1)` for a clamped input read several times, `let t1 = …` otherwise, then the
/// final expression. A chain like x^4 prints as `let t1 = x * x` and `t1 * t1`, showing what is computed.
pub(crate) fn with_lets(f: &Formula) -> String {
    let (mut out, roots) = with_lets_of(f, &[f.root]);
    out.push_str(&roots[0]);
    out
}

/// [`with_lets`] for several roots of `f.ir` (the channels of a colour formula, say): the `let` lines shared
/// by all of them, then each root's expression.
pub(crate) fn with_lets_of(f: &Formula, roots: &[NodeId]) -> (String, Vec<String>) {
    let counts = f.ir.use_counts_of(roots);
    let mut names: HashMap<NodeId, String> = HashMap::new();
    // The names given so far, for the uniqueness check (a scan of `names` made printing quadratic).
    let mut given: std::collections::HashSet<String> = std::collections::HashSet::new();
    let mut out = String::new();
    let taken = |s: &str| f.params.iter().any(|p| p.name == s) || s == "pi";
    let mut k = 0;
    let top = roots.iter().map(|r| r.index()).max().unwrap_or(0);
    for id in f.ir.ids().take(top) {
        let n = f.ir.node(id);
        if counts[id.index()] < 2 || roots.contains(&id) || matches!(n, Node::Const(_) | Node::Input(_) | Node::Param(_) | Node::Column(_)) {
            continue;
        }
        let mut name = match n {
            Node::Call(crate::builtins::Builtin::Clamp, [x, ..]) => match f.ir.node(*x) {
                Node::Input(i) => i.name().to_lowercase(),
                _ => String::new(),
            },
            _ => String::new(),
        };
        while name.is_empty() || taken(&name) || given.contains(&name) {
            k += 1;
            name = format!("t{k}");
        }
        out.push_str("let ");
        out.push_str(&name);
        out.push_str(" = ");
        write(f, id, &mut out, &names);
        out.push('\n');
        given.insert(name.clone());
        names.insert(id, name);
    }
    let exprs = roots
        .iter()
        .map(|r| {
            let mut e = String::new();
            write(f, *r, &mut e, &names);
            e
        })
        .collect();
    (out, exprs)
}

/// The formula as a source file of lobe's language, for people to read and edit (`lobe import`): `@name`,
/// the parameters (`param x = 0.5 in 0..1`, `param flag = true`, `param c = rgb(…)`), `@domain raw` (the
/// expression is taken as written: no input or result clamp added), the shared subexpressions as `let`s and
/// the final expression, or `rgb(r, g, b)` for a colour formula. The implicit `n` is not declared.
pub fn source(f: &Formula, header: &str) -> String {
    let mut out = String::new();
    for line in header.lines() {
        out.push_str("# ");
        out.push_str(line);
        out.push('\n');
    }
    out.push_str(&format!("@name \"{}\"\n", f.display_name().replace('"', "'")));
    for p in &f.params {
        match p.kind {
            _ if p.span.is_none() && p.name == "n" => {}
            ParamKind::Float => out.push_str(&format!("param {} = {} in {}..{}\n", p.name, number(p.default), number(p.lo), number(p.hi))),
            ParamKind::Bool => out.push_str(&format!("param {} = {}\n", p.name, p.default != 0.0)),
            ParamKind::Color(0) => {
                let base = p.name.strip_suffix(".r").unwrap_or(&p.name);
                let ch: Vec<String> = ["r", "g", "b"]
                    .iter()
                    .map(|c| f.params.iter().find(|q| q.name == format!("{base}.{c}")).map_or(0.0, |q| q.default))
                    .map(number)
                    .collect();
                out.push_str(&format!("param {base} = rgb({})\n", ch.join(", ")));
            }
            ParamKind::Color(_) => {}
        }
    }
    out.push_str("@domain raw\n");
    let (ir, roots) = f.merged_roots();
    let merged = Formula { ir, root: roots[roots.len() - 1], rgb: None, ..f.clone() };
    let (lets, exprs) = with_lets_of(&merged, &roots);
    out.push_str(&lets);
    if exprs.len() == 3 {
        out.push_str(&format!("rgb({})\n", exprs.join(", ")));
    } else {
        out.push_str(&exprs.concat());
        out.push('\n');
    }
    out
}

/// Writes the expression at `id`. Iterative (an explicit stack of pending pieces), so a 500 000-deep chain
/// that the front end accepts prints instead of overflowing the stack.
///
/// Comparisons print as `a < b`, selects as `c ? a : b` (`c && a` and `c || b` for the selects `&&` and
/// `||` lower to, `!c` for `c == 0` on a bool), so the text parses back to the same values. The language
/// types what the IR does not: a node is a bool when it is a comparison, a bool parameter, or a select of
/// bools; each operand is printed for the type its place needs, a bool where a number is needed as
/// `c ? 1 : 0`, a number where a bool is needed as `x != 0` (the select's own test), 0 and 1 as `false` and
/// `true`. Cost: linear in the printed nodes (bool-ness is memoised per call).
fn write(f: &Formula, id: NodeId, out: &mut String, names: &HashMap<NodeId, String>) {
    use crate::builtins::Builtin as B;
    enum Item {
        /// A node to print; `min` is the precedence below which it needs parentheses (`None`: top level);
        /// `want_bool`: the place needs a bool.
        Node(NodeId, Option<u8>, bool),
        Text(&'static str),
    }
    let mut memo: HashMap<NodeId, bool> = HashMap::new();
    let top = is_bool(f, id, &mut memo);
    let mut stack = vec![Item::Node(id, None, top)];
    while let Some(item) = stack.pop() {
        let (id, min, want) = match item {
            Item::Text(t) => {
                out.push_str(t);
                continue;
            }
            Item::Node(id, min, want) => (id, min, want),
        };
        let n = f.ir.node(id);
        let natural = is_bool(f, id, &mut memo);
        let open = |out: &mut String, stack: &mut Vec<Item>, p: u8| {
            if min.is_some_and(|m| p < m) {
                out.push('(');
                stack.push(Item::Text(")"));
            }
        };
        // Conversions between the node's type and the place's. A select takes the place's type (its branches
        // are printed for it) unless it is named, and a name has the type it was printed with.
        let named = min.is_some() && names.contains_key(&id);
        let fixed = named || !matches!(n, Node::Call(B::Select, _));
        if want && !natural && fixed {
            match n.as_const() {
                Some(c) if c == 0.0 && c.is_sign_positive() => out.push_str("false"),
                Some(1.0) => out.push_str("true"),
                _ => {
                    open(out, &mut stack, 4);
                    stack.push(Item::Text(" != 0"));
                    stack.push(Item::Node(id, Some(5), false));
                }
            }
            continue;
        }
        if !want && natural && fixed {
            open(out, &mut stack, 1);
            stack.push(Item::Text(" ? 1 : 0"));
            stack.push(Item::Node(id, Some(2), true));
            continue;
        }
        if min.is_some() {
            if let Some(name) = names.get(&id) {
                out.push_str(name);
                continue;
            }
        }
        let p = prec(n);
        match n {
            Node::Call(B::Select, [c, a, b]) => {
                let (bool_a, bool_b) = (is_bool(f, *a, &mut memo), is_bool(f, *b, &mut memo));
                if want && bool_a && f.ir.node(*b) == &Node::constant(0.0) {
                    open(out, &mut stack, 3);
                    stack.push(Item::Node(*a, Some(4), true));
                    stack.push(Item::Text(" && "));
                    stack.push(Item::Node(*c, Some(3), true));
                } else if want && bool_b && f.ir.node(*a) == &Node::constant(1.0) {
                    open(out, &mut stack, 2);
                    stack.push(Item::Node(*b, Some(3), true));
                    stack.push(Item::Text(" || "));
                    stack.push(Item::Node(*c, Some(2), true));
                } else {
                    open(out, &mut stack, 1);
                    stack.push(Item::Node(*b, Some(1), want));
                    stack.push(Item::Text(" : "));
                    stack.push(Item::Node(*a, Some(0), want));
                    stack.push(Item::Text(" ? "));
                    stack.push(Item::Node(*c, Some(2), true));
                }
                continue;
            }
            Node::Call(op @ (B::Lt | B::Le | B::Eq | B::Ne), [a, b, _]) => {
                // `==` on bools when both sides are bools or 0/1 constants, at least one a bool.
                let mut boolish = |x: NodeId| {
                    let c = f.ir.node(x).as_const();
                    (c.is_some_and(|c| c == 1.0 || c.to_bits() == 0), is_bool(f, x, &mut memo))
                };
                let ((ca, ba), (cb, bb)) = (boolish(*a), boolish(*b));
                let on_bools = matches!(op, B::Eq | B::Ne) && (ca || ba) && (cb || bb) && (ba || bb);
                if on_bools && *op == B::Eq && f.ir.node(*b) == &Node::constant(0.0) {
                    open(out, &mut stack, 7);
                    out.push('!');
                    stack.push(Item::Node(*a, Some(7), true));
                    continue;
                }
                open(out, &mut stack, 4);
                stack.push(Item::Node(*b, Some(5), on_bools));
                stack.push(Item::Text(match op {
                    B::Lt => " < ",
                    B::Le => " <= ",
                    B::Eq => " == ",
                    _ => " != ",
                }));
                stack.push(Item::Node(*a, Some(5), on_bools));
                continue;
            }
            _ => {}
        }
        open(out, &mut stack, p);
        match n {
            Node::Const(b) => out.push_str(&literal(f64::from_bits(*b))),
            Node::Input(i) => out.push_str(i.name()),
            Node::Param(p) => out.push_str(&f.params[*p as usize].name),
            // Not in the language: printed as the shading program's column, for dumps only.
            Node::Column(k) => out.push_str(&format!("column{k}")),
            Node::Neg(a) => {
                out.push('-');
                stack.push(Item::Node(*a, Some(7), false));
            }
            Node::Binary(op, a, b) => {
                // The right operand needs parentheses at equal precedence: for - and / by algebra, and for
                // + and * because floating-point addition and multiplication are not associative
                // (a + (b + c) differs from a + b + c), so the text shows the evaluation order the IR has.
                stack.push(Item::Node(*b, Some(p + 1), false));
                stack.push(Item::Text(match op {
                    BinOp::Add => " + ",
                    BinOp::Sub => " - ",
                    BinOp::Mul => " * ",
                    BinOp::Div => " / ",
                }));
                stack.push(Item::Node(*a, Some(p), false));
            }
            Node::Call(b, args) => {
                out.push_str(b.name());
                out.push('(');
                stack.push(Item::Text(")"));
                for (k, a) in args[..b.arity()].iter().enumerate().rev() {
                    stack.push(Item::Node(*a, Some(0), false));
                    if k > 0 {
                        stack.push(Item::Text(", "));
                    }
                }
            }
        }
    }
}

/// Whether `id` is a bool to the language: a comparison, a bool parameter, or a select whose branches are
/// bools (or the constants 0 and 1, with at least one bool). Iterative over chains of selects.
fn is_bool(f: &Formula, id: NodeId, memo: &mut HashMap<NodeId, bool>) -> bool {
    use crate::builtins::Builtin as B;
    // `None`: a select, decided from its branches.
    let direct = |n: &Node| match n {
        Node::Call(B::Lt | B::Le | B::Eq | B::Ne, _) => Some(true),
        Node::Param(p) => Some(f.params[*p as usize].kind == ParamKind::Bool),
        Node::Call(B::Select, _) => None,
        _ => Some(false),
    };
    let mut stack = vec![id];
    while let Some(&top) = stack.last() {
        if memo.contains_key(&top) {
            stack.pop();
            continue;
        }
        let n = f.ir.node(top);
        let Node::Call(B::Select, [_, a, b]) = *n else {
            memo.insert(top, direct(n).unwrap_or(false));
            stack.pop();
            continue;
        };
        let pending: Vec<NodeId> =
            [a, b].into_iter().filter(|x| direct(f.ir.node(*x)).is_none() && !memo.contains_key(x)).collect();
        if !pending.is_empty() {
            stack.extend(pending);
            continue;
        }
        let kind = |x: NodeId, memo: &HashMap<NodeId, bool>| {
            let n = f.ir.node(x);
            if let Some(c) = n.as_const() {
                return (c == 1.0 || c.to_bits() == 0).then_some(false);
            }
            direct(n).unwrap_or_else(|| memo.get(&x).copied().unwrap_or(false)).then_some(true)
        };
        // Each branch: Some(true) a bool, Some(false) a 0/1 constant, None a number.
        let (ka, kb) = (kind(a, memo), kind(b, memo));
        let v = ka.is_some() && kb.is_some() && (ka == Some(true) || kb == Some(true));
        memo.insert(top, v);
        stack.pop();
    }
    memo[&id]
}
