//! One source file's syntax: the modules it declares, every path it writes into its own crate
//! (`crate::…`, `super::…`, `self::…`) with its line, and, for the crate root, the names the
//! root defines or imports. Code under `#[cfg(test)]` declares modules (its files are test
//! files) but writes no paths.

use std::path::{Path, PathBuf};

use proc_macro2::{Spacing, Span, TokenStream, TokenTree};
use syn::visit::{self, Visit};
use syn::{Attribute, Item, Meta, UseTree};

use crate::error::Error;

/// Where a file sits: its path and the module it is.
#[derive(Debug, Clone)]
pub struct FileCtx {
    pub path: PathBuf,
    /// The module path of the file (`[]` for lib.rs, `["fusion", "thread"]` for
    /// `src/fusion/thread.rs`).
    pub module: Vec<String>,
    /// lib.rs, main.rs, a `mod.rs` or a file named by `#[path]`: its child modules are beside
    /// it, not in a folder named after it.
    pub mod_rs: bool,
    /// Reached only through `#[cfg(test)]`.
    pub test_only: bool,
}

/// A path into the crate, resolved from `crate::`, `super::` or `self::`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Written {
    /// The module the path is written in.
    pub module: Vec<String>,
    /// The path from the crate root: `super::graph::Graph` in `fusion` is `["graph", "Graph"]`.
    pub target: Vec<String>,
    /// The path as written, segments joined by `::`.
    pub text: String,
    /// The line of the segment that names `target[0]`.
    pub line: usize,
}

/// A `mod name;` declaration and the files that may hold it, in the order rustc tries them.
#[derive(Debug, Clone)]
pub struct ModDecl {
    pub module: Vec<String>,
    /// Candidate files with whether each is a mod-rs file.
    pub candidates: Vec<(PathBuf, bool)>,
    pub test_only: bool,
    pub line: usize,
}

/// A `use` at the crate root: the name it binds (`None` for a glob) and its path as written.
#[derive(Debug, Clone)]
pub struct RootUse {
    pub name: Option<String>,
    pub segments: Vec<String>,
}

/// What one file holds.
#[derive(Debug, Default)]
pub struct FileScan {
    pub mods: Vec<ModDecl>,
    /// Inline modules (`mod x { … }`) outside `#[cfg(test)]`, by module path.
    pub inline_mods: Vec<Vec<String>>,
    pub paths: Vec<Written>,
    /// Names of items defined at the crate root (a file whose module is `[]`).
    pub root_items: Vec<String>,
    pub root_uses: Vec<RootUse>,
    /// `#[macro_export]` macros: their name and the module that defines them.
    pub exported_macros: Vec<(String, Vec<String>)>,
}

/// Parses `source`, the text of the file `ctx` describes.
pub fn scan(ctx: &FileCtx, source: &str) -> Result<FileScan, Error> {
    let file = syn::parse_file(source).map_err(|e| Error::Parse {
        path: ctx.path.clone(),
        line: e.span().start().line,
        message: e.to_string(),
    })?;
    let dir = ctx.path.parent().map(Path::to_path_buf).unwrap_or_default();
    let children = if ctx.mod_rs {
        dir.clone()
    } else {
        let stem = ctx.path.file_stem().map(|s| s.to_owned()).unwrap_or_default();
        dir.join(stem)
    };
    let mut visitor = Visitor {
        file_module: ctx.module.clone(),
        file_dir: dir,
        file_children: children,
        inline: Vec::new(),
        in_test: ctx.test_only,
        blocks: 0,
        out: FileScan::default(),
    };
    visitor.visit_file(&file);
    Ok(visitor.out)
}

/// Whether the attributes make the item test code: `#[cfg(test)]`, `#[cfg(all(test, …))]`.
/// `#[cfg(doc)]` counts too: such items (imports for intra-doc links) exist only when rustdoc
/// builds, and are documentation, not product code.
pub fn is_cfg_test(attrs: &[Attribute]) -> bool {
    attrs.iter().any(|attr| attr.path().is_ident("cfg") && attr.parse_args::<Meta>().is_ok_and(|m| not_product(&m)))
}

fn not_product(meta: &Meta) -> bool {
    let args = |list: &syn::MetaList| {
        list.parse_args_with(syn::punctuated::Punctuated::<Meta, syn::Token![,]>::parse_terminated)
            .map(|args| args.into_iter().collect::<Vec<_>>())
            .unwrap_or_default()
    };
    match meta {
        Meta::Path(path) => path.is_ident("test") || path.is_ident("doc"),
        Meta::List(list) if list.path.is_ident("all") => args(list).iter().any(not_product),
        Meta::List(list) if list.path.is_ident("any") => {
            let any = args(list);
            !any.is_empty() && any.iter().all(not_product)
        }
        _ => false,
    }
}

fn path_attr(attrs: &[Attribute]) -> Option<PathBuf> {
    attrs.iter().find_map(|attr| match &attr.meta {
        Meta::NameValue(nv) if nv.path.is_ident("path") => match &nv.value {
            syn::Expr::Lit(syn::ExprLit { lit: syn::Lit::Str(s), .. }) => Some(PathBuf::from(s.value())),
            _ => None,
        },
        _ => None,
    })
}

fn line(span: Span) -> usize {
    span.start().line
}

struct Visitor {
    file_module: Vec<String>,
    file_dir: PathBuf,
    /// Where the file's own `mod x;` declarations look for `x.rs` and `x/mod.rs`.
    file_children: PathBuf,
    /// Inline modules (`mod x { … }`) the visitor is inside: name and children's folder.
    inline: Vec<(String, PathBuf)>,
    in_test: bool,
    /// Depth of blocks (function bodies): items in them are not the module's items.
    blocks: usize,
    out: FileScan,
}

impl Visitor {
    fn module(&self) -> Vec<String> {
        let mut module = self.file_module.clone();
        module.extend(self.inline.iter().map(|(name, _)| name.clone()));
        module
    }

    fn children_dir(&self) -> &Path {
        self.inline.last().map_or(&self.file_children, |(_, dir)| dir)
    }

    fn at_crate_root(&self) -> bool {
        self.file_module.is_empty() && self.inline.is_empty() && self.blocks == 0 && !self.in_test
    }

    /// Enters an attributed node: `#[cfg(test)]` makes everything under it test code.
    fn enter(&mut self, attrs: &[Attribute]) -> bool {
        let was = self.in_test;
        self.in_test |= is_cfg_test(attrs);
        was
    }

    /// Records a path given as its segments and their lines, if it starts at the crate root
    /// or climbs there (`crate`, `super`, `self`).
    fn path(&mut self, segments: &[(String, usize)], suffix: &str) {
        if self.in_test || segments.is_empty() {
            return;
        }
        let module = self.module();
        let (mut target, consumed) = match segments[0].0.as_str() {
            "crate" => (Vec::new(), 1),
            "self" => (module.clone(), 1),
            "super" => {
                let mut base = module.clone();
                let mut consumed = 0;
                while segments.get(consumed).is_some_and(|(s, _)| s == "super") {
                    if base.pop().is_none() {
                        return;
                    }
                    consumed += 1;
                }
                (base, consumed)
            }
            _ => return,
        };
        target.extend(segments[consumed..].iter().map(|(s, _)| s.clone()));
        if target.is_empty() {
            return;
        }
        let line = segments.get(consumed).or(segments.last()).map_or(0, |(_, l)| *l);
        let text = segments.iter().map(|(s, _)| s.as_str()).collect::<Vec<_>>().join("::") + suffix;
        self.out.paths.push(Written { module, target, text, line });
    }

    fn use_tree(&mut self, tree: &UseTree, prefix: &mut Vec<(String, usize)>) {
        match tree {
            UseTree::Path(p) => {
                prefix.push((p.ident.to_string(), line(p.ident.span())));
                self.use_tree(&p.tree, prefix);
                prefix.pop();
            }
            UseTree::Name(n) => self.use_leaf(prefix, &n.ident, None),
            UseTree::Rename(r) => self.use_leaf(prefix, &r.ident, Some(r.rename.to_string())),
            UseTree::Glob(_) => {
                self.path(prefix, "::*");
                if self.at_crate_root() {
                    let segments = prefix.iter().map(|(s, _)| s.clone()).collect();
                    self.out.root_uses.push(RootUse { name: None, segments });
                }
            }
            UseTree::Group(g) => {
                for tree in &g.items {
                    self.use_tree(tree, prefix);
                }
            }
        }
    }

    fn use_leaf(&mut self, prefix: &[(String, usize)], ident: &syn::Ident, rename: Option<String>) {
        let mut segments = prefix.to_vec();
        // `use a::{self}` names `a` itself.
        if ident != "self" {
            segments.push((ident.to_string(), line(ident.span())));
        }
        self.path(&segments, "");
        if self.at_crate_root()
            && let Some((last, _)) = segments.last()
        {
            let name = rename.unwrap_or_else(|| last.clone());
            self.out
                .root_uses
                .push(RootUse { name: Some(name), segments: segments.into_iter().map(|(s, _)| s).collect() });
        }
    }

    /// Paths inside macro invocations and attribute arguments are tokens, not syntax:
    /// `crate :: a :: b` and `super :: … :: a` sequences are read from the token stream.
    fn tokens(&mut self, stream: TokenStream) {
        let tokens: Vec<TokenTree> = stream.into_iter().collect();
        let mut i = 0;
        while i < tokens.len() {
            match &tokens[i] {
                TokenTree::Group(group) => self.tokens(group.stream()),
                TokenTree::Ident(ident) if (ident == "crate" || ident == "super") && !after_path_sep(&tokens, i) => {
                    let mut segments = vec![(ident.to_string(), line(ident.span()))];
                    let mut j = i + 1;
                    while let Some(next) = path_sep_then_ident(&tokens, j) {
                        segments.push((next.to_string(), line(next.span())));
                        j += 3;
                    }
                    if segments.len() > 1 {
                        self.path(&segments, "");
                    }
                    i = j;
                    continue;
                }
                _ => {}
            }
            i += 1;
        }
    }
}

fn is_colon(token: Option<&TokenTree>, spacing: Spacing) -> bool {
    matches!(token, Some(TokenTree::Punct(p)) if p.as_char() == ':' && p.spacing() == spacing)
}

fn after_path_sep(tokens: &[TokenTree], i: usize) -> bool {
    i >= 2 && is_colon(tokens.get(i - 2), Spacing::Joint) && is_colon(tokens.get(i - 1), Spacing::Alone)
}

fn path_sep_then_ident(tokens: &[TokenTree], j: usize) -> Option<&proc_macro2::Ident> {
    if !(is_colon(tokens.get(j), Spacing::Joint) && is_colon(tokens.get(j + 1), Spacing::Alone)) {
        return None;
    }
    match tokens.get(j + 2) {
        Some(TokenTree::Ident(ident)) => Some(ident),
        _ => None,
    }
}

fn item_attrs(item: &Item) -> &[Attribute] {
    match item {
        Item::Const(i) => &i.attrs,
        Item::Enum(i) => &i.attrs,
        Item::ExternCrate(i) => &i.attrs,
        Item::Fn(i) => &i.attrs,
        Item::ForeignMod(i) => &i.attrs,
        Item::Impl(i) => &i.attrs,
        Item::Macro(i) => &i.attrs,
        Item::Mod(i) => &i.attrs,
        Item::Static(i) => &i.attrs,
        Item::Struct(i) => &i.attrs,
        Item::Trait(i) => &i.attrs,
        Item::TraitAlias(i) => &i.attrs,
        Item::Type(i) => &i.attrs,
        Item::Union(i) => &i.attrs,
        Item::Use(i) => &i.attrs,
        _ => &[],
    }
}

/// The name an item defines in its module's namespace (uses and impls define none here).
fn item_name(item: &Item) -> Option<String> {
    let ident = match item {
        Item::Const(i) => &i.ident,
        Item::Enum(i) => &i.ident,
        Item::ExternCrate(i) => i.rename.as_ref().map_or(&i.ident, |(_, r)| r),
        Item::Fn(i) => &i.sig.ident,
        Item::Macro(i) => i.ident.as_ref()?,
        Item::Static(i) => &i.ident,
        Item::Struct(i) => &i.ident,
        Item::Trait(i) => &i.ident,
        Item::TraitAlias(i) => &i.ident,
        Item::Type(i) => &i.ident,
        Item::Union(i) => &i.ident,
        _ => return None,
    };
    Some(ident.to_string())
}

impl<'ast> Visit<'ast> for Visitor {
    fn visit_item(&mut self, item: &'ast Item) {
        let was = self.enter(item_attrs(item));
        if self.at_crate_root()
            && let Some(name) = item_name(item)
        {
            self.out.root_items.push(name);
        }
        if let Item::Macro(mac) = item
            && let Some(ident) = &mac.ident
            && mac.attrs.iter().any(|a| a.path().is_ident("macro_export"))
            && !self.in_test
        {
            self.out.exported_macros.push((ident.to_string(), self.module()));
        }
        visit::visit_item(self, item);
        self.in_test = was;
    }

    fn visit_item_mod(&mut self, m: &'ast syn::ItemMod) {
        let name = m.ident.to_string();
        let mut module = self.module();
        module.push(name.clone());
        let declared_path = path_attr(&m.attrs);
        match &m.content {
            None => {
                let candidates = match declared_path {
                    // Outside inline modules `#[path]` is relative to the file's folder.
                    Some(p) if self.inline.is_empty() => vec![(self.file_dir.join(p), true)],
                    Some(p) => vec![(self.children_dir().join(p), true)],
                    None => {
                        let dir = self.children_dir();
                        vec![(dir.join(format!("{name}.rs")), false), (dir.join(&name).join("mod.rs"), true)]
                    }
                };
                let decl = ModDecl { module, candidates, test_only: self.in_test, line: line(m.ident.span()) };
                self.out.mods.push(decl);
            }
            Some((_, items)) => {
                if !self.in_test {
                    self.out.inline_mods.push(module);
                }
                let dir = self.children_dir().join(declared_path.unwrap_or_else(|| PathBuf::from(&name)));
                self.inline.push((name, dir));
                for item in items {
                    self.visit_item(item);
                }
                self.inline.pop();
            }
        }
    }

    fn visit_item_use(&mut self, u: &'ast syn::ItemUse) {
        // `use ::x` names another crate.
        if u.leading_colon.is_none() {
            self.use_tree(&u.tree, &mut Vec::new());
        }
    }

    fn visit_path(&mut self, path: &'ast syn::Path) {
        if path.leading_colon.is_none() {
            let segments: Vec<(String, usize)> =
                path.segments.iter().map(|s| (s.ident.to_string(), line(s.ident.span()))).collect();
            self.path(&segments, "");
        }
        visit::visit_path(self, path);
    }

    fn visit_macro(&mut self, mac: &'ast syn::Macro) {
        visit::visit_macro(self, mac);
        self.tokens(mac.tokens.clone());
    }

    fn visit_meta_list(&mut self, list: &'ast syn::MetaList) {
        visit::visit_meta_list(self, list);
        self.tokens(list.tokens.clone());
    }

    fn visit_block(&mut self, block: &'ast syn::Block) {
        self.blocks += 1;
        visit::visit_block(self, block);
        self.blocks -= 1;
    }

    fn visit_impl_item(&mut self, item: &'ast syn::ImplItem) {
        let attrs: &[Attribute] = match item {
            syn::ImplItem::Const(i) => &i.attrs,
            syn::ImplItem::Fn(i) => &i.attrs,
            syn::ImplItem::Type(i) => &i.attrs,
            syn::ImplItem::Macro(i) => &i.attrs,
            _ => &[],
        };
        let was = self.enter(attrs);
        visit::visit_impl_item(self, item);
        self.in_test = was;
    }

    fn visit_trait_item(&mut self, item: &'ast syn::TraitItem) {
        let attrs: &[Attribute] = match item {
            syn::TraitItem::Const(i) => &i.attrs,
            syn::TraitItem::Fn(i) => &i.attrs,
            syn::TraitItem::Type(i) => &i.attrs,
            syn::TraitItem::Macro(i) => &i.attrs,
            _ => &[],
        };
        let was = self.enter(attrs);
        visit::visit_trait_item(self, item);
        self.in_test = was;
    }

    fn visit_local(&mut self, local: &'ast syn::Local) {
        let was = self.enter(&local.attrs);
        visit::visit_local(self, local);
        self.in_test = was;
    }

    fn visit_stmt_macro(&mut self, mac: &'ast syn::StmtMacro) {
        let was = self.enter(&mac.attrs);
        visit::visit_stmt_macro(self, mac);
        self.in_test = was;
    }

    fn visit_field(&mut self, field: &'ast syn::Field) {
        let was = self.enter(&field.attrs);
        visit::visit_field(self, field);
        self.in_test = was;
    }

    fn visit_variant(&mut self, variant: &'ast syn::Variant) {
        let was = self.enter(&variant.attrs);
        visit::visit_variant(self, variant);
        self.in_test = was;
    }

    fn visit_arm(&mut self, arm: &'ast syn::Arm) {
        let was = self.enter(&arm.attrs);
        visit::visit_arm(self, arm);
        self.in_test = was;
    }

    fn visit_field_value(&mut self, field: &'ast syn::FieldValue) {
        let was = self.enter(&field.attrs);
        visit::visit_field_value(self, field);
        self.in_test = was;
    }

    fn visit_expr(&mut self, expr: &'ast syn::Expr) {
        // `#[cfg(test)]` on an expression statement (`#[cfg(test)] self.check();`).
        let attrs: &[Attribute] = match expr {
            syn::Expr::Call(e) => &e.attrs,
            syn::Expr::MethodCall(e) => &e.attrs,
            syn::Expr::Block(e) => &e.attrs,
            syn::Expr::Macro(e) => &e.attrs,
            syn::Expr::Assign(e) => &e.attrs,
            syn::Expr::If(e) => &e.attrs,
            _ => &[],
        };
        let was = self.enter(attrs);
        visit::visit_expr(self, expr);
        self.in_test = was;
    }
}
