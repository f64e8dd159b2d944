//! The lowerer's declarations: the metadata lines (`@name`, `@cite`, `@domain`) and the parameters (`param`,
//! typed and ranged), collected before any statement is lowered.

use super::*;

impl<'a, 's> Lowerer<'a, 's> {
    /// `@name`, `@cite` and `@domain` (which sets [`Lowerer::raw`]).
    pub(super) fn meta(&mut self) -> Meta {
        let mut meta = Meta::default();
        let mut seen: HashMap<&str, Span> = HashMap::new();
        for s in &self.ast.stmts {
            let StmtKind::Meta { key, value, value_span, quoted } = &s.kind else { continue };
            if !quoted && key.name != "domain" {
                // Only `@domain raw` takes a bare word; the message is the parser's for a missing string.
                self.error(
                    Diagnostic::error(format!(
                        "expected a string in double quotes after `@{}`, found name `{value}`",
                        key.name
                    ))
                    .at(*value_span, "expected a string in double quotes")
                    .hint(format!("metadata takes a string in double quotes: `@{} \"…\"`", key.name)),
                );
                continue;
            }
            if key.name == "domain" {
                if let Some(first) = seen.insert("domain", key.span) {
                    let d = Diagnostic::error("`@domain` is given twice")
                        .at(key.span, "second one here")
                        .also(first, "first one here")
                        .hint("keep one of them");
                    self.error(d);
                    continue;
                }
                match *value {
                    "raw" => self.raw = true,
                    "brdf" => {}
                    other => self.error(
                        Diagnostic::error(format!("unknown domain `{other}`"))
                            .at(*value_span, "not a domain")
                            .hint("`@domain brdf` (the default: cosines clamped to 0..1, result at least 0) or `@domain raw` \
                                   (GLSL semantics, nothing clamped)"),
                    ),
                }
                continue;
            }
            let slot = match key.name {
                "name" => &mut meta.name,
                "cite" => &mut meta.citation,
                other => {
                    let mut d = Diagnostic::error(format!("unknown metadata key `@{other}`"))
                        .at(key.span, "not a metadata key");
                    let synonym = match other.to_ascii_lowercase().as_str() {
                        "title" | "label" | "display" | "model" => Some("name"),
                        "citation" | "ref" | "reference" | "source" | "eq" | "paper" => Some("cite"),
                        _ => None,
                    };
                    d = match synonym.or_else(|| crate::front::suggest(other, ["name", "cite"])) {
                        Some(k) => d.hint(format!("did you mean `@{k}`? The keys are `@name`, `@cite` and `@domain`")),
                        None => d.hint("the keys are `@name \"display name\"`, `@cite \"source, equation\"` and `@domain raw`"),
                    };
                    self.error(d);
                    continue;
                }
            };
            if let Some(first) = seen.get(key.name) {
                let d = Diagnostic::error(format!("`@{}` is given twice", key.name))
                    .at(key.span, "second one here")
                    .also(*first, "first one here")
                    .hint("keep one of them");
                self.error(d);
                continue;
            }
            seen.insert(key.name, key.span);
            *slot = Some(value.to_string());
        }
        meta
    }

    /// The builtin `name` calls: one of the language's, or with [`Lowerer::internal`] any of the table's.
    pub(super) fn builtin(&self, name: &str) -> Option<Builtin> {
        Builtin::from_name(name).filter(|b| self.internal || !b.is_internal())
    }

    /// What a name already means, if it is reserved (input, frame vector, shorthand, constant, function). An
    /// internal builtin's name is free unless the text may call it.
    pub(super) fn reserved(&self, name: &str) -> Option<String> {
        if let Some(i) = Input::from_name(name) {
            return Some(format!("the input {} ({})", i.name(), i.describe()));
        }
        if name == "pi" {
            return Some("the constant pi".into());
        }
        if FRAME.contains(&name) {
            return Some(format!("the frame vector {name}"));
        }
        if SHORTHANDS.contains(&name) {
            return Some(format!("the shorthand {name}"));
        }
        if let Some((_, doc)) = derived(name) {
            return Some(format!("the function {name} ({doc})"));
        }
        self.builtin(name).map(|b| format!("the function {}", signature(b)))
    }

    pub(super) fn declare_params(&mut self) {
        let mut declared: HashMap<&'s str, Span> = HashMap::new();
        for s in &self.ast.stmts {
            let StmtKind::Param { name, default, range } = &s.kind else { continue };
            if let Some(what) = self.reserved(name.name) {
                self.error(
                    Diagnostic::error(format!("`param {}` would shadow {what}", name.name))
                        .at(name.span, "this name is taken")
                        .hint("choose another parameter name"),
                );
                continue;
            }
            if let Some(first) = declared.get(name.name) {
                self.error(
                    Diagnostic::error(format!("parameter `{}` is declared twice", name.name))
                        .at(name.span, "second declaration")
                        .also(*first, "first declared here")
                        .hint("keep one declaration"),
                );
                continue;
            }
            declared.insert(name.name, name.span);
            let default = match *default {
                ParamDefault::Num(l) => l,
                other => {
                    self.declare_typed_param(*name, other, *range, s.span);
                    continue;
                }
            };
            let (lo, hi) = match range {
                Some((lo, hi)) => (*lo, *hi),
                None if name.name == "n" => {
                    let at = Lit { value: 0.0, span: default.span };
                    (Lit { value: N_DEFAULT.1, ..at }, Lit { value: N_DEFAULT.2, ..at })
                }
                None => {
                    let at = Lit { value: 0.0, span: default.span };
                    (Lit { value: f64::NEG_INFINITY, ..at }, Lit { value: f64::INFINITY, ..at })
                }
            };
            // An invalid range is reported, but the parameter is still declared so its uses do not cascade.
            self.check_range(name, default, lo, hi, range.is_some());
            let decl = ParamDecl {
                name: name.name.to_string(),
                default: default.value,
                lo: lo.value,
                hi: hi.value,
                span: Some(s.span),
                kind: ParamKind::Float,
            };
            if name.name == "n" {
                self.params[0] = decl;
            } else if self.params.len() + 3 >= u16::MAX as usize {
                self.error(Diagnostic::error("too many parameters").at(name.span, "here").hint("use fewer than 65000"));
            } else {
                self.param_names.insert(name.name, ParamRef::Float(self.params.len() as u16));
                self.params.push(decl);
            }
        }
    }

    /// A bool (`param b = true`) or colour (`param c = rgb(r, g, b)`) parameter: range 0..1, no `in`.
    fn declare_typed_param(&mut self, name: Ident<'s>, default: ParamDefault<'s>, range: Option<(Lit, Lit)>, span: Span) {
        let kind = if matches!(default, ParamDefault::Bool(..)) { "bool" } else { "colour" };
        if name.name == "n" {
            self.error(
                Diagnostic::error(format!("`n` cannot be a {kind} parameter"))
                    .at(default.span(), "not a number")
                    .hint("`n` is the specular exponent: `param n = 100 in 1..1000`"),
            );
            return;
        }
        if let Some((lo, hi)) = range {
            self.error(
                Diagnostic::error(format!("a {kind} parameter has no range"))
                    .at(lo.span.join(hi.span), "remove this range")
                    .hint(format!("a {kind} parameter always ranges over 0..1")),
            );
        }
        if self.params.len() + 3 >= u16::MAX as usize {
            self.error(Diagnostic::error("too many parameters").at(name.span, "here").hint("use fewer than 65000"));
            return;
        }
        let first = self.params.len() as u16;
        let decl = |n: String, v: f64, kind: ParamKind| ParamDecl { name: n, default: v, lo: 0.0, hi: 1.0, span: Some(span), kind };
        match default {
            ParamDefault::Bool(b, _) => {
                self.params.push(decl(name.name.to_string(), if b { 1.0 } else { 0.0 }, ParamKind::Bool));
                self.param_names.insert(name.name, ParamRef::Bool(first));
            }
            ParamDefault::Color(ctor, lits, _) => {
                if ctor.name != "rgb" && ctor.name != "vec3" {
                    self.error(
                        Diagnostic::error(format!("a parameter's default cannot be `{}(…)`", ctor.name))
                            .at(ctor.span, "not a colour")
                            .hint("a colour parameter is written `param base = rgb(0.8, 0.6, 0.2)`"),
                    );
                }
                for l in lits {
                    if !(0.0..=1.0).contains(&l.value) {
                        self.error(
                            Diagnostic::error(format!("colour channel {} of `{}` is outside 0..1", crate::ir::print::number(l.value), name.name))
                                .at(l.span, "outside 0..1")
                                .hint("colour channels range over 0..1"),
                        );
                    }
                }
                for (k, (l, ch)) in lits.iter().zip(["r", "g", "b"]).enumerate() {
                    self.params.push(decl(format!("{}.{ch}", name.name), l.value, ParamKind::Color(k as u8)));
                }
                self.param_names.insert(name.name, ParamRef::Color(first));
            }
            ParamDefault::Num(_) => unreachable!("float parameters are declared by the caller"),
        }
    }

    /// Validates `default in lo..hi`; reports and returns false when invalid.
    fn check_range(&mut self, name: &Ident, default: Lit, lo: Lit, hi: Lit, explicit: bool) -> bool {
        // The implicit range of a parameter other than `n` is unbounded on purpose; written numbers must be finite.
        let written: &[Lit] = if explicit { &[default, lo, hi] } else { &[default] };
        for &l in written {
            if !l.value.is_finite() {
                self.error(
                    Diagnostic::error(format!("parameter `{}` has a non-finite value", name.name))
                        .at(l.span, "not a finite number")
                        .hint("defaults and range bounds must be finite numbers"),
                );
                return false;
            }
        }
        if lo.value > hi.value {
            self.error(
                Diagnostic::error(format!(
                    "the range of `{}` is empty: {} is greater than {}",
                    name.name,
                    crate::ir::print::number(lo.value),
                    crate::ir::print::number(hi.value)
                ))
                .at(lo.span.join(hi.span), "lower bound above upper bound")
                .hint(format!(
                    "write the smaller bound first: `in {}..{}`",
                    crate::ir::print::number(hi.value),
                    crate::ir::print::number(lo.value)
                )),
            );
            return false;
        }
        if !(lo.value..=hi.value).contains(&default.value) {
            let range = format!("{}..{}", crate::ir::print::number(lo.value), crate::ir::print::number(hi.value));
            let mut d = Diagnostic::error(format!(
                "the default {} of `{}` is outside its range {range}",
                crate::ir::print::number(default.value),
                name.name
            ))
            .at(default.span, "outside the range");
            if explicit {
                d = d.also(lo.span.join(hi.span), "the range");
            }
            let hint = if explicit {
                "choose a default within the range, or widen the range".to_string()
            } else {
                format!("`{}` has the implicit range {range}; give a range with `in lo..hi` to change it", name.name)
            };
            self.error(d.hint(hint));
            return false;
        }
        true
    }
}
